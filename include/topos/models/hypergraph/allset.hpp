// topos/models/hypergraph/allset.hpp
// AllSet (Chien et al., "You are AllSet", ICLR 2022; TopoModelX AllSet): per layer two set
// functions, nodes -> hyperedges then hyperedges -> nodes, each relu(decoder(mean over the
// set of relu(encoder(x)) W))), the encoder and decoder TopoModelX's bias-free MLPs. Parameters
// layers.<i>.{vertex2edge,edge2vertex}.{encoder,decoder}.<k>.weight and .conv.weight.
// TopoModelX's AllSet passes mlp_activation=None, which breaks MLPs of two or more layers; with
// topomodelx_compatible that is an error, otherwise None is the identity.
#pragma once

#include "topos/nn/conv.hpp"

#include <functional>
#include <optional>

namespace topos::models {

/// The normalisation inside a TopoModelX MLP (its `norm_layer`).
enum class MlpNorm { none, layer_norm, batch_norm };

/// TopoModelX's hypergraph MLP (allset_layer.MLP): [Linear(no bias), norm?, act, Dropout] per
/// hidden width but the last, then Linear(no bias), Dropout; numbered like torch.nn.Sequential.
/// `activation` is absent (std::nullopt) where TopoModelX received None.
class TopoMLPImpl : public torch::nn::Module {
 public:
  TopoMLPImpl(std::int64_t in, std::int64_t width, int layers, std::optional<nn::Update> activation,
              MlpNorm norm, double dropout, bool topomodelx_compatible)
      : dropout_(dropout) {
    if (layers < 1)
      throw std::invalid_argument("MLP: mlp_num_layers (" + std::to_string(layers) +
                                  ") must be positive");
    if (layers > 1 && !activation && topomodelx_compatible)
      throw std::invalid_argument("MLP: mlp_activation None with " + std::to_string(layers) +
                                  " MLP layers fails in TopoModelX (name an activation)");
    int idx = 0;
    for (int l = 0; l < layers; ++l) {
      auto lin = register_module(
          std::to_string(idx++),
          torch::nn::Linear(torch::nn::LinearOptions(l == 0 ? in : width, width).bias(false)));
      steps_.push_back([lin](const torch::Tensor& x) { return lin->forward(x); });
      if (l + 1 == layers) break;
      if (norm == MlpNorm::layer_norm) {
        auto ln = register_module(std::to_string(idx++),
                                  torch::nn::LayerNorm(torch::nn::LayerNormOptions({width})));
        steps_.push_back([ln](const torch::Tensor& x) { return ln->forward(x); });
      } else if (norm == MlpNorm::batch_norm) {
        auto bn = register_module(std::to_string(idx++), torch::nn::BatchNorm1d(width));
        steps_.push_back([bn](const torch::Tensor& x) { return bn->forward(x); });
      }
      const auto act = activation.value_or(nn::Update::none);
      steps_.push_back([act](const torch::Tensor& x) { return nn::apply_update(x, act); });
      ++idx;  // the activation module
      steps_.push_back(
          [this](const torch::Tensor& x) { return torch::dropout(x, dropout_, is_training()); });
      ++idx;  // Dropout
    }
  }
  torch::Tensor forward(torch::Tensor x) {
    for (auto& s : steps_) x = s(x);
    return torch::dropout(x, dropout_, is_training());
  }

 private:
  double dropout_;
  std::vector<std::function<torch::Tensor(const torch::Tensor&)>> steps_;
};
TORCH_MODULE(TopoMLP);

struct AllSetOptions {
  AllSetOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, layer_dropout) = 0.2;
  TORCH_ARG(int, mlp_num_layers) = 2;
  TORCH_ARG(std::optional<nn::Update>,
            mlp_activation) = nn::Update::relu;  ///< nullopt: TopoModelX's None
  TORCH_ARG(double, mlp_dropout) = 0.0;
  TORCH_ARG(MlpNorm, mlp_norm) = MlpNorm::none;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

/// One set function (TopoModelX AllSetBlock): relu(decoder(Conv(relu(encoder(x)), A))) with the
/// mean over each target's sources (Conv with aggr_norm and a relu update).
class AllSetBlockImpl : public torch::nn::Module {
 public:
  AllSetBlockImpl(std::int64_t in, const AllSetOptions& o) : dropout_(o.layer_dropout()) {
    const auto h = o.hidden_channels();
    encoder = register_module("encoder",
                              TopoMLP(in, h, o.mlp_num_layers(), o.mlp_activation(), o.mlp_norm(),
                                      o.mlp_dropout(), o.topomodelx_compatible()));
    decoder = register_module("decoder",
                              TopoMLP(h, h, o.mlp_num_layers(), o.mlp_activation(), o.mlp_norm(),
                                      o.mlp_dropout(), o.topomodelx_compatible()));
    conv = register_module(
        "conv", nn::Conv(nn::ConvOptions(h, h).aggr_norm(true).update_func(nn::Update::relu)));
  }
  torch::Tensor forward(const torch::Tensor& x_source, const nn::SparseOperator& A) {
    auto x = torch::dropout(torch::relu(encoder->forward(x_source)), dropout_, is_training());
    return torch::relu(decoder->forward(conv->forward(x, A)));
  }
  TopoMLP encoder{nullptr}, decoder{nullptr};
  nn::Conv conv{nullptr};

 private:
  double dropout_;
};
TORCH_MODULE(AllSetBlock);

class AllSetImpl : public torch::nn::Module {
 public:
  explicit AllSetImpl(const AllSetOptions& o) : options(o) {
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      v2e_.push_back(layer->register_module(
          "vertex2edge", AllSetBlock(l == 0 ? o.in_channels() : o.hidden_channels(), o)));
      e2v_.push_back(layer->register_module("edge2vertex", AllSetBlock(o.hidden_channels(), o)));
      list->push_back(layer);
    }
  }
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(torch::Tensor x0, const nn::SparseOperator& incidence_1) {
    nn::check_node_features("AllSet", x0, incidence_1);
    const auto Bt = incidence_1.t();
    torch::Tensor x1;
    for (std::size_t l = 0; l < v2e_.size(); ++l) {
      x1 = torch::dropout(v2e_[l]->forward(x0, Bt), options.layer_dropout(), is_training());
      x0 =
          torch::dropout(e2v_[l]->forward(x1, incidence_1), options.layer_dropout(), is_training());
    }
    return {x0, x1};
  }
  AllSetOptions options;

 private:
  std::vector<AllSetBlock> v2e_, e2v_;
};
TORCH_MODULE(AllSet);

}  // namespace topos::models
