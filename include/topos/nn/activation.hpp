// topos/nn/activation.hpp
// The activation functions every model names (TopoModelX's update functions, the MLPs' gelu and
// selu): the enum, its names, applying one to a tensor, and which of them the product kernels
// apply in their row loop (fusable, epilogue_of).
#pragma once

#include "topos/nn/kernels/epilogue.hpp"

#include <torch/torch.h>

#include <stdexcept>
#include <string>

namespace topos::nn {

/// The activation functions of every model: TopoModelX's update functions and the MLPs' (HOPNet's
/// gelu and selu); `none` is the identity.
enum class Activation { none, relu, sigmoid, tanh, elu, leaky_relu, gelu, selu };

inline Activation activation_from_string(const std::string& s) {
  if (s.empty() || s == "none" || s == "None" || s == "null") return Activation::none;
  if (s == "relu") return Activation::relu;
  if (s == "sigmoid") return Activation::sigmoid;
  if (s == "tanh") return Activation::tanh;
  if (s == "elu") return Activation::elu;
  if (s == "leaky_relu") return Activation::leaky_relu;
  if (s == "gelu") return Activation::gelu;
  if (s == "selu") return Activation::selu;
  throw std::invalid_argument("unknown activation '" + s +
                              "' (relu, sigmoid, tanh, elu, leaky_relu, gelu, selu, none)");
}

/// The name activation_from_string reads back ("none" for the identity).
inline std::string activation_name(Activation u) {
  switch (u) {
    case Activation::relu:
      return "relu";
    case Activation::sigmoid:
      return "sigmoid";
    case Activation::tanh:
      return "tanh";
    case Activation::elu:
      return "elu";
    case Activation::leaky_relu:
      return "leaky_relu";
    case Activation::gelu:
      return "gelu";
    case Activation::selu:
      return "selu";
    default:
      return "none";
  }
}

inline torch::Tensor apply_activation(const torch::Tensor& x, Activation u,
                                      double negative_slope = 0.01) {
  switch (u) {
    case Activation::relu:
      return torch::relu(x);
    case Activation::sigmoid:
      return torch::sigmoid(x);
    case Activation::tanh:
      return torch::tanh(x);
    case Activation::elu:  // on the CPU, the vectorised expm1 of the product kernels' epilogue
      return x.device().is_cpu() && x.is_floating_point() && x.numel() > 0
                 ? detail::EluFunction::apply(x)
                 : torch::elu(x);
    case Activation::leaky_relu:
      return torch::leaky_relu(x, negative_slope);
    case Activation::gelu:
      return torch::gelu(x);
    case Activation::selu:
      return torch::selu(x);
    default:
      return x;
  }
}

/// Deprecated: the earlier names of the activation enum and its functions.
using Update = Activation;
inline Activation update_from_string(const std::string& s) {
  return activation_from_string(s);
}
inline std::string update_name(Activation u) {
  return activation_name(u);
}
inline torch::Tensor apply_update(const torch::Tensor& x, Activation u,
                                  double negative_slope = 0.01) {
  return apply_activation(x, u, negative_slope);
}

/// The activations the product kernels apply in their row loop (spmm, linear_act), or none.
inline bool fusable(Activation u) {
  return u == Activation::none || u == Activation::relu || u == Activation::elu ||
         u == Activation::sigmoid;
}
inline detail::Epilogue epilogue_of(Activation u) {
  using detail::Epilogue;
  return u == Activation::relu      ? Epilogue::relu
         : u == Activation::elu     ? Epilogue::elu
         : u == Activation::sigmoid ? Epilogue::sigmoid
                                    : Epilogue::none;
}

}  // namespace topos::nn
