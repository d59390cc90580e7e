// topos/models/hypergraph/hypersage.hpp
// HyperSAGE (Arya et al., "HyperSAGE: generalizing inductive representation learning on
// hypergraphs", 2020; TopoModelX HyperSAGE): per layer, intra-edge generalised means
// m_e = (mean_{u∈e} x_u^p)^(1/p) (p = 2), inter-edge generalised means over a node's hyperedges
// weighted by their sizes, m_v = (mean_{e∋v} (|e| / Σ_{e'∋v} |e'| · m_e)^p)^(1/p), then
// σ(normalise(x + m) W). `alpha` > 0 samples at most alpha nodes per hyperedge (at random, on
// every call, as TopoModelX). TopoModelX normalises by the norm of the whole matrix; the
// default here is the paper's per-node normalisation (topomodelx_compatible for TopoModelX's).
// Parameters layers.<i>.weight (in × out).
#pragma once

#include "topos/nn/conv.hpp"

#include <cmath>

namespace topos::models {

struct HyperSAGEOptions {
  HyperSAGEOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(int, alpha) = -1;    ///< nodes sampled per hyperedge; -1: all
  TORCH_ARG(double, power) = 2;  ///< of the generalised means
  TORCH_ARG(nn::Update, update_func) = nn::Update::relu;
  TORCH_ARG(bool, uniform_initialization) =
      true;  ///< TopoModelX's "uniform"; false: xavier_uniform (gain 1.414)
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

class HyperSAGEImpl : public torch::nn::Module {
 public:
  explicit HyperSAGEImpl(const HyperSAGEOptions& o) : options(o) {
    if (o.alpha() == 0 || o.alpha() < -1)
      throw std::invalid_argument(
          "HyperSAGE: alpha must be -1 (every node of a hyperedge) or positive, got " +
          std::to_string(o.alpha()));
    if (o.update_func() != nn::Update::relu && o.update_func() != nn::Update::sigmoid)
      throw std::invalid_argument("HyperSAGE: update_func must be relu or sigmoid");
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      auto w = layer->register_parameter(
          "weight",
          torch::empty({l == 0 ? o.in_channels() : o.hidden_channels(), o.hidden_channels()}));
      torch::NoGradGuard g;
      if (o.uniform_initialization())
        w.uniform_(-1 / std::sqrt(double(w.size(1))), 1 / std::sqrt(double(w.size(1))));
      else
        nn::xavier_uniform(w);
      list->push_back(layer);
      weights_.push_back(w);
    }
  }
  /// x_0 (nodes) and the node × hyperedge incidence (its pattern); returns {x_0}.
  std::vector<torch::Tensor> forward(torch::Tensor x, const nn::SparseOperator& incidence_1) {
    nn::check_node_features("HyperSAGE", x, incidence_1);
    const auto P = incidence_1.pattern().to(x.scalar_type());
    const double p = options.power();
    for (auto& w : weights_) {
      const auto S = sampled(P);       // the nodes each hyperedge hears
      const auto size = S.col_sums();  // |e| as sampled
      const auto intra =
          (nn::spmm(S.t(), x.pow(p)) / size.unsqueeze(1)).pow(1 / p);  // hyperedges × C
      const auto share = nn::spmm(P, size.unsqueeze(1)).squeeze(1);    // Σ_{e∋v} |e|
      const auto weights = P.scaled(share.reciprocal(), size);         // |e| / Σ_{e'∋v} |e'|
      const auto degree = P.row_sums().unsqueeze(1);
      const auto inter =
          (nn::spmm(weights.with_values(weights.values.pow(p)), intra.pow(p)) / degree).pow(1 / p);
      const auto m = x + inter;
      const auto normalised =
          options.topomodelx_compatible() ? m / m.norm() : m / m.norm(2, 1, true).clamp_min(1e-12);
      x = nn::apply_update(normalised.matmul(w), options.update_func());
    }
    return {x};
  }
  HyperSAGEOptions options;

 private:
  // At most alpha nodes per hyperedge, drawn at random; the whole pattern when alpha is -1.
  nn::SparseOperator sampled(const nn::SparseOperator& P) const {
    if (options.alpha() < 0) return P;
    const auto Pt = P.t();
    const auto crow = Pt.crow.accessor<std::int64_t, 1>();
    const auto col = Pt.col.accessor<std::int64_t, 1>();
    std::vector<std::int64_t> r, c;
    std::vector<double> v;
    for (std::int64_t e = 0; e < Pt.rows; ++e) {
      const auto n = crow[e + 1] - crow[e];
      const auto pick = n <= options.alpha() ? torch::arange(n)
                                             : torch::randperm(n).narrow(0, 0, options.alpha());
      for (std::int64_t i = 0; i < pick.size(0); ++i)
        r.push_back(col[crow[e] + pick[i].item<std::int64_t>()]), c.push_back(e), v.push_back(1.0);
    }
    return nn::SparseOperator::from_triplets(P.rows, P.cols, r, c, v, P.values.scalar_type());
  }
  std::vector<torch::Tensor> weights_;
};
TORCH_MODULE(HyperSAGE);

}  // namespace topos::models
