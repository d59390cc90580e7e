// topos/models/combinatorial/hmc.hpp
// HMC (Hajij et al., "Topological deep learning: going beyond graph data", 2023; TopoModelX
// HMC): two levels of attention message passing on ranks 0-2 of a combinatorial complex.
// HBS: same-rank messages over an adjacency, weighted by a per-target softmax of
// leaky_relu(a·[m_i || m_j]); HBNS: both directions of an incidence, each with its own
// attention; sums of the messages reaching a rank, then relu.
// TopoModelX's HBS builds its neighbourhood as I·A with torch.sparse.mm, whose result lists each
// row's entries in descending column order while the softmax returns them ascending; pairing the
// two lists by position gives entry (i, j) the attention of the entry mirrored within row i. The
// compatible mode reproduces that (HMCOptions::topomodelx_compatible); the default pairs each
// entry with its own weight.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

/// Same-rank attention (m_hop = 1): "weight.0" (in × out), "att_weight.0" (2·out × 1).
class HBSImpl : public torch::nn::Module {
 public:
  HBSImpl(std::int64_t in, std::int64_t out, double slope, bool softmax, nn::Update update,
          bool mirrored_rows = false)
      : slope_(slope), softmax_(softmax), mirrored_rows_(mirrored_rows), update_(update) {
    auto w = nn::submodule_group(*this, "weight"), a = nn::submodule_group(*this, "att_weight");
    weight = w->register_parameter("0", torch::empty({in, out}));
    att_weight = a->register_parameter("0", torch::empty({2 * out, 1}));
    nn::xavier_uniform(weight);
    nn::xavier_uniform(att_weight);
  }
  torch::Tensor forward(const torch::Tensor& x, const nn::SparseOperator& N) {
    const auto m = x.matmul(weight);
    const auto C = m.size(1);
    const auto raw = nn::pair_scores(N, m, att_weight.narrow(0, C, C), m,
                                     att_weight.narrow(0, 0, C));  // [m_i || m_j]: target first
    auto att =
        nn::attention_weights(N, raw, nn::Update::leaky_relu, slope_,
                              softmax_ ? nn::AttentionNorm::softmax : nn::AttentionNorm::row_sum);
    if (mirrored_rows_) att = att.index_select(0, N.row_mirror());
    return nn::apply_update(nn::spmm(N.with_values(att * N.values.to(att.scalar_type())), m),
                            update_);
  }
  torch::Tensor weight, att_weight;

 private:
  double slope_;
  bool softmax_, mirrored_rows_;
  nn::Update update_;
};
TORCH_MODULE(HBS);

/// Attention both ways along an incidence N (target × source): "w_s" (source in × target out),
/// "w_t" (target in × source out), "att_weight" ((target out + source out) × 1). Returns
/// (message on the source cells, message on the target cells).
class HBNSImpl : public torch::nn::Module {
 public:
  HBNSImpl(std::int64_t s_in, std::int64_t s_out, std::int64_t t_in, std::int64_t t_out,
           double slope, bool softmax, nn::Update update)
      : s_out_(s_out), t_out_(t_out), slope_(slope), softmax_(softmax), update_(update) {
    w_s = register_parameter("w_s", torch::empty({s_in, t_out}));
    w_t = register_parameter("w_t", torch::empty({t_in, s_out}));
    att_weight = register_parameter("att_weight", torch::empty({t_out + s_out, 1}));
    nn::xavier_uniform(w_s);
    nn::xavier_uniform(w_t);
    nn::xavier_uniform(att_weight);
  }
  std::pair<torch::Tensor, torch::Tensor> forward(const torch::Tensor& x_source,
                                                  const torch::Tensor& x_target,
                                                  const nn::SparseOperator& N) {
    const auto s = x_source.matmul(w_s), t = x_target.matmul(w_t);
    const auto Nt = N.t();
    const auto norm = softmax_ ? nn::AttentionNorm::softmax : nn::AttentionNorm::row_sum;
    // source -> target: a·[s_j || t_i]; target -> source: TopoModelX swaps the halves of a at
    // s_out (the same split as the first only when s_out == t_out).
    const auto a = att_weight.reshape({-1});
    const auto e = nn::attention_weights(
        N, nn::pair_scores(N, s, a.narrow(0, 0, t_out_), t, a.narrow(0, t_out_, s_out_)),
        nn::Update::leaky_relu, slope_, norm);
    const auto b = torch::cat({a.narrow(0, s_out_, t_out_), a.narrow(0, 0, s_out_)});
    const auto f = nn::attention_weights(
        Nt, nn::pair_scores(Nt, t, b.narrow(0, 0, s_out_), s, b.narrow(0, s_out_, t_out_)),
        nn::Update::leaky_relu, slope_, norm);
    auto on_source = nn::spmm(Nt.with_values(f * Nt.values.to(f.scalar_type())), t);
    auto on_target = nn::spmm(N.with_values(e * N.values.to(e.scalar_type())), s);
    return {nn::apply_update(on_source, update_), nn::apply_update(on_target, update_)};
  }
  torch::Tensor w_s, w_t, att_weight;

 private:
  std::int64_t s_out_, t_out_;
  double slope_;
  bool softmax_;
  nn::Update update_;
};
TORCH_MODULE(HBNS);

/// Per layer: (in, intermediate, out) channels of ranks 0, 1, 2.
using HMCChannels = std::vector<std::array<std::array<std::int64_t, 3>, 3>>;

struct HMCOptions {
  explicit HMCOptions(HMCChannels c) : channels_per_layer_(std::move(c)) {}
  TORCH_ARG(HMCChannels, channels_per_layer);
  TORCH_ARG(double, negative_slope) = 0.2;
  TORCH_ARG(nn::Update, update_func_attention) = nn::Update::relu;
  TORCH_ARG(nn::Update, update_func_aggregation) = nn::Update::relu;
  TORCH_ARG(bool,
            topomodelx_compatible) = false;  ///< HBS attention paired with mirrored entries (above)
};

class HMCImpl : public torch::nn::Module {
 public:
  explicit HMCImpl(const HMCOptions& o) : options(o) {
    const auto& c = o.channels_per_layer();
    if (c.empty()) throw std::invalid_argument("HMC: channels_per_layer is empty");
    for (std::size_t i = 0; i + 1 < c.size(); ++i)
      if (c[i][2] != c[i + 1][0])
        throw std::invalid_argument("HMC: layer " + std::to_string(i) +
                                    "'s output channels differ from layer " +
                                    std::to_string(i + 1) + "'s input channels");
    auto list = register_module("layers", torch::nn::ModuleList());
    const double s = o.negative_slope();
    const auto u = o.update_func_attention();
    const bool mir = o.topomodelx_compatible();
    for (const auto& [in, mid, out] : c) {
      auto m = std::make_shared<torch::nn::Module>();
      layers_.push_back(
          {m->register_module("hbs_0_level1", HBS(in[0], mid[0], s, true, u, mir)),
           m->register_module("hbns_0_1_level1", HBNS(in[1], mid[1], in[0], mid[0], s, true, u)),
           m->register_module("hbns_1_2_level1", HBNS(in[2], mid[2], in[1], mid[1], s, true, u)),
           m->register_module("hbs_0_level2", HBS(mid[0], out[0], s, true, u, mir)),
           m->register_module("hbns_0_1_level2", HBNS(mid[1], out[1], mid[0], out[0], s, true, u)),
           m->register_module("hbs_1_level2", HBS(mid[1], out[1], s, true, u, mir)),
           m->register_module("hbns_1_2_level2", HBNS(mid[2], out[2], mid[1], out[1], s, true, u)),
           m->register_module("hbs_2_level2", HBS(mid[2], out[2], s, true, u, mir))});
      list->push_back(m);
    }
  }
  /// (x_0, x_1, x_2); adjacency_0, adjacency_1, coadjacency_2; incidences B_01 (n0 × n1), B_12.
  std::vector<torch::Tensor> forward(std::vector<torch::Tensor> x,
                                     const nn::SparseOperator& adjacency_0,
                                     const nn::SparseOperator& adjacency_1,
                                     const nn::SparseOperator& coadjacency_2,
                                     const nn::SparseOperator& incidence_1,
                                     const nn::SparseOperator& incidence_2) {
    auto agg = [&](std::vector<torch::Tensor> m) {
      return nn::aggregate_messages(m, nn::Aggr::sum, options.update_func_aggregation());
    };
    for (auto& l : layers_) {
      const auto x00 = l.hbs_0_1->forward(x[0], adjacency_0);
      const auto [x01, x10] = l.hbns_01_1->forward(x[1], x[0], incidence_1);
      const auto [x12, x21] = l.hbns_12_1->forward(x[2], x[1], incidence_2);
      const auto y0 = agg({x00, x10}), y1 = agg({x01, x21}), y2 = agg({x12});
      const auto z01 = l.hbns_01_2->forward(y1, y0, incidence_1).first;
      const auto z12 = l.hbns_12_2->forward(y2, y1, incidence_2).first;
      x = {agg({l.hbs_0_2->forward(y0, adjacency_0)}),
           agg({z01, l.hbs_1_2->forward(y1, adjacency_1)}),
           agg({z12, l.hbs_2_2->forward(y2, coadjacency_2)})};
    }
    return x;
  }
  HMCOptions options;

 private:
  struct Layer {
    HBS hbs_0_1;
    HBNS hbns_01_1, hbns_12_1;
    HBS hbs_0_2;
    HBNS hbns_01_2;
    HBS hbs_1_2;
    HBNS hbns_12_2;
    HBS hbs_2_2;
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(HMC);

}  // namespace topos::models
