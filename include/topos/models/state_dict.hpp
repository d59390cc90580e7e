// topos/models/state_dict.hpp
// Weights as TopoModelX saves them: a state_dict read into a module by parameter name (a folder
// of <name>.npy files or a torch.save'd .pt file), and tensors read and written as .npy.
#pragma once

#include "topos/data/json.hpp"
#include "topos/data/npy.hpp"
#include "topos/nn/serialization.hpp"

#include <torch/torch.h>

#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace topos::models {

/// A float32 tensor from a .npy file (any numeric dtype); errors name the file.
inline torch::Tensor read_npy_tensor(const std::filesystem::path& path) {
  if (!std::filesystem::exists(path)) throw data::DataError(path.string() + ": missing file");
  const auto a = data::read_npy(path.string());
  auto v = a.as<float>();
  return torch::from_blob(v.data(), a.shape, torch::kFloat).clone();
}

/// Writes a tensor as float32 .npy, atomically.
inline void write_npy_tensor(const std::filesystem::path& path, const torch::Tensor& t) {
  const auto c = t.detach().to(torch::kCPU, torch::kFloat).contiguous();
  data::write_npy(path.string(), c.sizes().vec(), c.data_ptr<float>());
}

/// Loads a TopoModelX state_dict into `m` by parameter name: from a folder of <name>.npy files
/// (the names listed in state_dict.json beside it when present) or a torch.save'd .pt file. A
/// missing, unexpected or mis-shaped tensor is an error naming it.
inline void load_state_dict(torch::nn::Module& m, const std::filesystem::path& source) {
  std::map<std::string, torch::Tensor> dict;
  if (std::filesystem::is_directory(source)) {
    const auto listing = source.parent_path() / "state_dict.json";
    if (std::filesystem::exists(listing)) {
      for (const auto& e : data::read_json_file(listing)) {
        if (!e.is_array() || e.empty() || !e[0].is_string())
          throw data::DataError(listing.string() + ": entries must be [name, shape]");
        const auto name = e[0].get<std::string>();
        auto t = read_npy_tensor(source / (name + ".npy"));
        if (e.size() > 1 && e[1].is_array() &&
            e[1].get<std::vector<std::int64_t>>() != t.sizes().vec())
          throw data::DataError((source / (name + ".npy")).string() +
                                ": shape differs from state_dict.json");
        dict[name] = t;
      }
    } else {
      for (const auto& f : std::filesystem::directory_iterator(source))
        if (f.path().extension() == ".npy")
          dict[f.path().stem().string()] = read_npy_tensor(f.path());
    }
  } else {
    dict = nn::read_tensor_dict(source.string());
  }
  nn::load_parameters(m, dict, source.string());
}

}  // namespace topos::models
