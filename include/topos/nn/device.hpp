// topos/nn/device.hpp
// Choosing the device a model runs on from a user's word: "cpu", "cuda" (or "cuda:N"), or
// "auto" (the GPU when this LibTorch has CUDA and one is visible, else the CPU). Asking for CUDA
// where there is none is an error that says why, not a crash inside LibTorch.
#pragma once

#include <torch/torch.h>

#include <stdexcept>
#include <string>

namespace topos::nn {

/// Whether this LibTorch was built with CUDA and sees at least one GPU.
inline bool cuda_available() {
  return torch::cuda::is_available();
}

/// The device `name` names; `local_rank` picks the GPU of a data-parallel worker for "cuda" and
/// "auto" (GPU local_rank modulo the visible count).
inline torch::Device device_from_string(const std::string& name, int local_rank = 0) {
  const auto gpu = [&](int index) {
    if (!cuda_available())
      throw std::invalid_argument(
          "--device " + name + ": no CUDA device: this LibTorch " +
          std::string(torch::cuda::device_count() == 0 ? "has no CUDA support or sees no GPU"
                                                       : "cannot use its GPUs") +
          " (build against a CUDA LibTorch, see docs/training-at-scale.md, or use --device cpu)");
    const auto n = static_cast<int>(torch::cuda::device_count());
    if (index >= n)
      throw std::invalid_argument("--device " + name + ": GPU " + std::to_string(index) +
                                  " does not exist (" + std::to_string(n) + " visible)");
    return torch::Device(torch::kCUDA, static_cast<c10::DeviceIndex>(index));
  };
  if (name == "cpu") return torch::kCPU;
  if (name == "auto")
    return cuda_available() ? gpu(local_rank % static_cast<int>(torch::cuda::device_count()))
                            : torch::Device(torch::kCPU);
  if (name == "cuda")
    return gpu(cuda_available() ? local_rank % static_cast<int>(torch::cuda::device_count()) : 0);
  if (name.rfind("cuda:", 0) == 0) {
    const std::string idx = name.substr(5);
    if (idx.empty() || idx.find_first_not_of("0123456789") != std::string::npos || idx.size() > 4)
      throw std::invalid_argument("--device " + name + ": expected cuda:<index>");
    return gpu(std::stoi(idx));
  }
  throw std::invalid_argument("--device " + name + ": expected cpu, cuda, cuda:<index> or auto");
}

}  // namespace topos::nn
