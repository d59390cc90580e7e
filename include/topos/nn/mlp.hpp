// topos/nn/mlp.hpp
// The MLP block of HOPNet (spec 6.1): Linear(in, hid), act, [(Linear(hid, hid), act) × (L-2)],
// Linear(hid, out), optional act, optional LayerNorm(out). With L = 1 only Linear(in, out) and an
// optional act (never LayerNorm). Submodules are numbered like torch.nn.Sequential, so parameter
// names ("0.weight", "2.bias", "4.weight") match the reference's checkpoints.
#pragma once

#include <torch/torch.h>

#include <stdexcept>
#include <string>

namespace topos::nn {

enum class Activation { relu, gelu, elu, selu };

inline Activation activation_from_string(const std::string& s) {
  if (s == "relu") return Activation::relu;
  if (s == "gelu") return Activation::gelu;
  if (s == "elu") return Activation::elu;
  if (s == "selu") return Activation::selu;
  throw std::invalid_argument("unknown activation '" + s + "' (relu, gelu, elu, selu)");
}
inline const char* to_string(Activation a) {
  switch (a) {
    case Activation::relu:
      return "relu";
    case Activation::gelu:
      return "gelu";
    case Activation::elu:
      return "elu";
    default:
      return "selu";
  }
}

struct MlpOptions {
  MlpOptions(std::int64_t in, std::int64_t hidden, std::int64_t out)
      : in_(in), hidden_(hidden), out_(out) {}
  TORCH_ARG(std::int64_t, in);
  TORCH_ARG(std::int64_t, hidden);
  TORCH_ARG(std::int64_t, out);
  TORCH_ARG(int, layers) = 2;
  TORCH_ARG(Activation, activation) = Activation::relu;
  TORCH_ARG(bool, final_activation) = true;
  TORCH_ARG(bool, layer_norm) = true;
};

class MlpImpl : public torch::nn::Module {
 public:
  explicit MlpImpl(const MlpOptions& o) : options(o) {
    if (o.in() <= 0 || o.out() <= 0 || o.hidden() <= 0 || o.layers() < 1)
      throw std::invalid_argument("Mlp: sizes must be positive and layers >= 1");
    int idx = 0;
    auto add = [&](auto module) {
      register_module(std::to_string(idx++), module.ptr());
      layers_.emplace_back(module);
    };
    auto add_linear = [&](std::int64_t i, std::int64_t out) { add(torch::nn::Linear(i, out)); };
    auto add_act = [&] {
      switch (o.activation()) {
        case Activation::relu:
          add(torch::nn::ReLU(torch::nn::ReLUOptions().inplace(true)));
          break;
        case Activation::gelu:
          add(torch::nn::GELU());
          break;
        case Activation::elu:
          add(torch::nn::ELU());
          break;
        case Activation::selu:
          add(torch::nn::SELU());
          break;
      }
    };
    if (o.layers() == 1) {
      add_linear(o.in(), o.out());
      if (o.final_activation()) add_act();
    } else {
      add_linear(o.in(), o.hidden());
      add_act();
      for (int l = 0; l < o.layers() - 2; ++l) {
        add_linear(o.hidden(), o.hidden());
        add_act();
      }
      add_linear(o.hidden(), o.out());
      if (o.final_activation()) add_act();
      if (o.layer_norm())
        add(torch::nn::LayerNorm(torch::nn::LayerNormOptions({o.out()}).eps(1e-5)));
    }
  }
  torch::Tensor forward(torch::Tensor x) {
    for (auto& m : layers_) x = m.forward(x);
    return x;
  }
  /// The first Linear layer, and the rest of the MLP applied to its output. A caller that knows
  /// its input is a concatenation can apply the weight's column blocks separately.
  torch::nn::Linear first_linear() const { return layers_.front().get<torch::nn::Linear>(); }
  torch::Tensor forward_after_first(torch::Tensor z) {
    for (std::size_t i = 1; i < layers_.size(); ++i) z = layers_[i].forward(z);
    return z;
  }
  MlpOptions options;

 private:
  std::vector<torch::nn::AnyModule> layers_;
};
TORCH_MODULE(Mlp);

}  // namespace topos::nn
