// topos/models/hypergraph/allset.hpp
// AllSet (Chien et al., "You are AllSet", ICLR 2022; TopoModelX AllSet): per layer two set
// functions, nodes -> hyperedges then hyperedges -> nodes, each relu(decoder(relu(mean over the
// set of relu(encoder(x)) W))), the encoder and decoder TopoModelX's bias-free MLPs, with dropout
// after the encoder and after each set function. Parameters
// layers.<i>.{vertex2edge,edge2vertex}.{encoder,decoder}.<k>.weight and .conv.weight.
// TopoModelX's AllSet passes mlp_activation=None, which breaks MLPs of two or more layers; with
// topomodelx_compatible that is an error, otherwise None is the identity. Written as an operator
// schedule (allset_schedule); TopoMLP, the same MLP as a module, serves AllSetTransformer.
#pragma once

#include "topos/nn/operator_schedule.hpp"

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
  TopoMLPImpl(std::int64_t in, std::int64_t width, int layers,
              std::optional<nn::Activation> activation, MlpNorm norm, double dropout,
              bool topomodelx_compatible)
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
        steps_.push_back([ln](const torch::Tensor& x) { return nn::layer_norm(x, *ln); });
      } else if (norm == MlpNorm::batch_norm) {
        auto bn = register_module(std::to_string(idx++), torch::nn::BatchNorm1d(width));
        steps_.push_back([bn](const torch::Tensor& x) { return bn->forward(x); });
      }
      const auto act = activation.value_or(nn::Activation::none);
      steps_.push_back([act](const torch::Tensor& x) { return nn::apply_activation(x, act); });
      ++idx;  // the activation module
      steps_.push_back(
          [this](const torch::Tensor& x) { return nn::dropout(x, dropout_, is_training()); });
      ++idx;  // Dropout
    }
  }
  torch::Tensor forward(torch::Tensor x) {
    for (auto& s : steps_) x = s(x);
    return nn::dropout(x, dropout_, is_training());
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
  TORCH_ARG(std::optional<nn::Activation>,
            mlp_activation) = nn::Activation::relu;  ///< nullopt: TopoModelX's None
  TORCH_ARG(double, mlp_dropout) = 0.0;
  TORCH_ARG(MlpNorm, mlp_norm) = MlpNorm::none;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

/// TopoModelX's hypergraph MLP (as TopoMLP) appended to a term or step: [Linear(no bias), norm?,
/// act, Dropout] per width but the last, then Linear(no bias), Dropout, at path.<k> numbered like
/// torch.nn.Sequential (the activation and Dropout take numbers too).
template <class C>
void append_topo_mlp(C& c, const std::string& path, std::int64_t width, const AllSetOptions& o) {
  const int layers = o.mlp_num_layers();
  int idx = 0;
  for (int l = 0; l < layers; ++l) {
    c.linear(path + "." + std::to_string(idx++), width, /*bias=*/false);
    if (l + 1 == layers) break;
    if (o.mlp_norm() == MlpNorm::layer_norm) c.layer_norm(path + "." + std::to_string(idx++));
    if (o.mlp_norm() == MlpNorm::batch_norm) c.batch_norm(path + "." + std::to_string(idx++));
    if (o.mlp_activation()) c.act(*o.mlp_activation());  // None: the identity
    c.dropout(o.mlp_dropout());
    idx += 2;  // the activation and Dropout modules
  }
  c.dropout(o.mlp_dropout());
}

/// The schedule: per layer two set functions (TopoModelX AllSetBlock), nodes → hyperedges then
/// hyperedges → nodes, each relu(decoder(relu(mean over the set of relu(encoder(x)) W))) with
/// dropout after the encoder and after the block; the mean is Conv's aggr_norm (row sums).
inline nn::OperatorSchedule allset_schedule(const AllSetOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  if (o.n_layers() < 1) throw std::invalid_argument("AllSet: n_layers must be >= 1");
  if (o.mlp_num_layers() < 1)
    throw std::invalid_argument("MLP: mlp_num_layers (" + std::to_string(o.mlp_num_layers()) +
                                ") must be positive");
  if (o.mlp_num_layers() > 1 && !o.mlp_activation() && o.topomodelx_compatible())
    throw std::invalid_argument("MLP: mlp_activation None with " +
                                std::to_string(o.mlp_num_layers()) +
                                " MLP layers fails in TopoModelX (name an activation)");
  const auto h = o.hidden_channels();
  const double drop = o.layer_dropout();
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels()).operator_input("incidence_1", 1, 0);
  auto block = [&](const std::string& path, int source, int target) {
    auto message = from(source);
    append_topo_mlp(message, path + ".encoder", h, o);
    message.act(Activation::relu).dropout(drop).conv(path + ".conv", h);
    if (target == 1)
      message.via_t("incidence_1", /*row_norm=*/true);
    else
      message.via("incidence_1", /*row_norm=*/true);
    auto step = into(target).sum(std::move(message.act(Activation::relu)));
    append_topo_mlp(step, path + ".decoder", h, o);
    return std::move(step.act(Activation::relu).dropout(drop));
  };
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    s.step(block(p + "vertex2edge", 0, 1));
    s.step(block(p + "edge2vertex", 1, 0));
  }
  s.output("x_0", 0).output("x_1", 1);
  return s;
}

class AllSetImpl : public nn::Cloneable<AllSetImpl, nn::OperatorNetworkImpl> {
 public:
  explicit AllSetImpl(const AllSetOptions& o) : Cloneable(allset_schedule(o)), options(o) {}
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1) of the last layer.
  std::vector<torch::Tensor> forward(const torch::Tensor& x0,
                                     const nn::SparseOperator& incidence_1) {
    nn::check_node_features("AllSet", x0, incidence_1);
    return run({{"x_0", x0}}, {{"incidence_1", incidence_1}}, {"x_0", "x_1"});
  }
  AllSetOptions options;
};
TORCH_MODULE(AllSet);

}  // namespace topos::models
