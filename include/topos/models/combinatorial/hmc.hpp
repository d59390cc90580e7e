// topos/models/combinatorial/hmc.hpp
// HMC (Hajij et al., "Topological deep learning: going beyond graph data", 2023; TopoModelX
// HMC): two levels of attention message passing on ranks 0-2 of a combinatorial complex.
// HBS: same-rank messages m = x W over an adjacency, weighted by a per-target softmax of
// leaky_relu(a·[m_i || m_j]); HBNS: both directions of an incidence, s = x_source W_s and
// t = x_target W_t, each direction scored on [s || t] with its own part of one vector; each
// message through update_func_attention, the messages reaching a rank summed, then
// update_func_aggregation. Level 1 updates every rank from the layer's input; level 2 updates
// them from level 1's (rank 0 by its adjacency alone, HBNS's messages on the source ranks).
// Written as an operator schedule (hmc_schedule): per level one parallel group of maps (states
// "m<r>", "s<ab>", "t<ab>") and one of messages. TopoModelX's parameter names are kept
// (layers.<i>.hbs_0_level1.weight.0 / .att_weight.0, layers.<i>.hbns_0_1_level1.w_s / .w_t /
// .att_weight); its HBS takes a as [a_t | a_s] and its reverse HBNS direction the vector rotated
// by the source's width (HmcAttention's offsets, HMC's own operation).
// TopoModelX's HBS builds its neighbourhood as I·A with torch.sparse.mm, whose result lists each
// row's entries in descending column order while the softmax returns them ascending; pairing the
// two lists by position gives entry (i, j) the attention of the entry mirrored within row i. The
// compatible mode reproduces that (HMCOptions::topomodelx_compatible); the default pairs each
// entry with its own weight.
#pragma once

#include "topos/models/query_attention.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <array>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace topos::models {

/// HMC's attention (HBS, HBNS), its own operation through the operator schedule's extension
/// point: messages x (the term's features) over A (or Aᵀ with `transposed`), entry (i, j)
/// weighted by the per-target softmax of leaky_relu(a_s·x_j + a_t·q_i), q the `queries` cochain,
/// times A's value. a is one parameter at `param` of x's plus q's widths, a_s and a_t read from
/// it cyclically from `source_offset` (default 0) and `target_offset` (default a_s's length):
/// TopoModelX's HBS takes [a_t | a_s], its reverse HBNS direction a rotated vector. With
/// `mirrored_rows`, entry k of a row takes the weight of the row's mirrored entry (the
/// (n-1-k)-th): TopoModelX's HBS pairs softmax weights in ascending column order with a
/// product's descending indices (SparseOperator::row_mirror).
struct HmcAttention : nn::Operation {
  HmcAttention(std::string op, std::string param, nn::CochainKey queries)
      : op(std::move(op)), param(std::move(param)), queries(std::move(queries)) {}
  std::string op, param;
  nn::CochainKey queries;
  std::vector<std::int64_t> shape;  ///< the parameter's (default: a vector)
  bool transposed = false;
  std::optional<std::int64_t> source_offset, target_offset;
  bool mirrored_rows = false;
  double negative_slope = 0.2;

  std::string name() const { return nn::operator_label(op, transposed); }
  std::string str(const std::string& x) const override {
    return "hmc_attend[" + param + "]" + name() + "·" + x;
  }
  nn::TermShape infer(nn::BuildContext& ctx, nn::TermShape x) const override {
    const auto dst = ctx.operator_from(op, x.rank, transposed).second;
    const auto fail = [&](const std::string& why) {
      ctx.fail("HMC attention over '" + name() + "' " + why);
    };
    const auto n =
        x.channels + query_width(ctx, queries, dst, "HMC attention over '" + name() + "'");
    for (const auto& offset : {source_offset, target_offset})
      if (offset && (*offset < 0 || *offset >= n))
        fail("needs offsets in [0, " + std::to_string(n) + "), got " + std::to_string(*offset));
    const auto s = shape.empty() ? std::vector<std::int64_t>{n} : shape;
    if (torch::empty(s).numel() != n) {
      std::ostringstream o;
      o << "needs " << n << " entries in '" << param << "', its shape " << torch::IntArrayRef(s)
        << " has " << torch::empty(s).numel();
      fail(o.str());
    }
    ctx.parameter(param, s, nn::ParameterInit::glorot(1.414));
    return {dst, x.channels};
  }
  torch::Tensor forward(nn::RunContext& ctx, const torch::Tensor& x) const override {
    const auto& A = transposed ? ctx.op_transposed(op) : ctx.op(op);
    const auto& q = query_rows(ctx, A, x, queries, name());
    const auto a = ctx.parameter(param).reshape({-1});
    const auto ck = x.size(1);
    const auto part = [&a](std::int64_t offset, std::int64_t n) {  // from offset on, wrapping
      return offset == 0 ? a.narrow(0, 0, n) : a.roll({-offset}).narrow(0, 0, n);
    };
    const auto a_s = part(source_offset.value_or(0), ck);
    const auto a_t = part(target_offset.value_or(ck), a.size(0) - ck);
    const auto raw = nn::entry_scores(A, nn::head_scores(x, a_s), nn::head_scores(q, a_t));
    const auto W = nn::attention_operator(A, raw, nn::Activation::leaky_relu, negative_slope,
                                          nn::AttentionNorm::softmax, 0, false,
                                          mirrored_rows ? A.row_mirror() : torch::Tensor());
    return nn::spmm(W, x.contiguous());
  }
};

/// Per layer: (in, intermediate, out) channels of ranks 0, 1, 2.
using HMCChannels = std::vector<std::array<std::array<std::int64_t, 3>, 3>>;

struct HMCOptions {
  explicit HMCOptions(HMCChannels c) : channels_per_layer_(std::move(c)) {}
  TORCH_ARG(HMCChannels, channels_per_layer);
  TORCH_ARG(double, negative_slope) = 0.2;
  TORCH_ARG(nn::Activation, update_func_attention) = nn::Activation::relu;
  TORCH_ARG(nn::Activation, update_func_aggregation) = nn::Activation::relu;
  TORCH_ARG(bool,
            topomodelx_compatible) = false;  ///< HBS attention paired with mirrored entries (above)
};

inline nn::OperatorSchedule hmc_schedule(const HMCOptions& o) {
  using namespace nn::ops;
  using nn::CochainKey;
  const auto& c = o.channels_per_layer();
  if (c.empty()) throw std::invalid_argument("HMC: channels_per_layer is empty");
  for (std::size_t i = 0; i < c.size(); ++i)
    for (const auto& ranks : c[i])
      for (const auto w : ranks)
        if (w <= 0)
          throw std::invalid_argument("HMC: layer " + std::to_string(i) +
                                      " needs positive channels");
  for (std::size_t i = 0; i + 1 < c.size(); ++i)
    if (c[i][2] != c[i + 1][0])
      throw std::invalid_argument("HMC: layer " + std::to_string(i) +
                                  "'s output channels differ from layer " + std::to_string(i + 1) +
                                  "'s input channels");
  nn::OperatorSchedule s;
  for (int r = 0; r < 3; ++r)
    s.input("x_" + std::to_string(r), r, c[0][0][static_cast<std::size_t>(r)])
        .output("x_" + std::to_string(r), r);
  s.operator_input("adjacency_0", 0, 0)
      .operator_input("adjacency_1", 1, 1)
      .operator_input("coadjacency_2", 2, 2)
      .operator_input("incidence_1", 1, 0)   // B_01: n0 × n1
      .operator_input("incidence_2", 2, 1);  // B_12: n1 × n2
  const auto u = o.update_func_attention();
  auto attention = [&](const std::string& op, const std::string& path, const CochainKey& queries,
                       std::int64_t n) {
    HmcAttention a(op, path, queries);
    a.shape = {n, 1};
    a.negative_slope = o.negative_slope();
    return a;
  };
  // HBS on rank r over `op`, from the map m<r>: a = [a_t | a_s].
  auto hbs = [&](const std::string& path, int r, std::int64_t out, const std::string& op) {
    const CochainKey m{r, "m" + std::to_string(r)};
    auto a = attention(op, path + ".att_weight.0", m, 2 * out);
    a.source_offset = out;
    a.target_offset = 0;
    a.mirrored_rows = o.topomodelx_compatible();
    return from(r, m.state).apply(std::move(a)).act(u);
  };
  // HBNS between ranks a < b over incidence B (n_a × n_b), from the maps s<ab> (rank b, a's
  // out channels) and t<ab> (rank a, b's out channels); a_s then a_t for the message on a, the
  // vector rotated by b's out channels for the message on b.
  auto hbns_on_target = [&](const std::string& path, int a, std::int64_t out_a, std::int64_t out_b,
                            const std::string& op) {
    const auto ab = std::to_string(a) + std::to_string(a + 1);
    return std::move(
        from(a + 1, "s" + ab)
            .apply(attention(op, path + ".att_weight", CochainKey{a, "t" + ab}, out_a + out_b))
            .act(u));
  };
  auto hbns_on_source = [&](const std::string& path, int a, std::int64_t out_a, std::int64_t out_b,
                            const std::string& op) {
    const auto ab = std::to_string(a) + std::to_string(a + 1);
    auto att = attention(op, path + ".att_weight", CochainKey{a + 1, "s" + ab}, out_a + out_b);
    att.transposed = true;
    att.source_offset = out_b;
    att.target_offset = 2 * out_b % (out_a + out_b);
    return from(a, "t" + ab).apply(std::move(att)).act(u);
  };
  // The maps of one level: m<r> for the HBS of the ranks in `hbs_ranks`, s01, t01, s12, t12.
  auto maps = [&](const std::string& p, const std::string& level,
                  const std::array<std::int64_t, 3>& w, std::initializer_list<int> hbs_ranks) {
    std::vector<nn::OperatorStep> steps;
    for (int r : hbs_ranks) {
      const auto R = std::to_string(r);
      steps.push_back(into(r, "m" + R)
                          .sum(from(r).weight(p + "hbs_" + R + "_" + level + ".weight.0",
                                              w[static_cast<std::size_t>(r)])));
    }
    for (int a : {0, 1}) {
      const auto ab = std::to_string(a) + std::to_string(a + 1);
      const auto q = p + "hbns_" + std::to_string(a) + "_" + std::to_string(a + 1) + "_" + level;
      steps.push_back(into(a + 1, "s" + ab).sum(from(a + 1).weight(q + ".w_s", w[a])));
      steps.push_back(into(a, "t" + ab).sum(from(a).weight(q + ".w_t", w[a + 1])));
    }
    return steps;
  };
  const auto g = o.update_func_aggregation();
  for (std::size_t l = 0; l < c.size(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    const auto &mid = c[l][1], &out = c[l][2];
    const auto h01 = p + "hbns_0_1_level1", h12 = p + "hbns_1_2_level1";
    s.parallel(maps(p, "level1", mid, {0}));
    s.parallel({into(0)
                    .sum(hbs(p + "hbs_0_level1", 0, mid[0], "adjacency_0"),
                         hbns_on_target(h01, 0, mid[0], mid[1], "incidence_1"))
                    .act(g),
                into(1)
                    .sum(hbns_on_source(h01, 0, mid[0], mid[1], "incidence_1"),
                         hbns_on_target(h12, 1, mid[1], mid[2], "incidence_2"))
                    .act(g),
                into(2).sum(hbns_on_source(h12, 1, mid[1], mid[2], "incidence_2")).act(g)});
    const auto k01 = p + "hbns_0_1_level2", k12 = p + "hbns_1_2_level2";
    s.parallel(maps(p, "level2", out, {0, 1, 2}));
    s.parallel({into(0).sum(hbs(p + "hbs_0_level2", 0, out[0], "adjacency_0")).act(g),
                into(1)
                    .sum(hbns_on_source(k01, 0, out[0], out[1], "incidence_1"),
                         hbs(p + "hbs_1_level2", 1, out[1], "adjacency_1"))
                    .act(g),
                into(2)
                    .sum(hbns_on_source(k12, 1, out[1], out[2], "incidence_2"),
                         hbs(p + "hbs_2_level2", 2, out[2], "coadjacency_2"))
                    .act(g)});
  }
  return s;
}

class HMCImpl : public nn::Cloneable<HMCImpl, nn::OperatorNetworkImpl> {
 public:
  explicit HMCImpl(const HMCOptions& o) : Cloneable(hmc_schedule(o)), options(o) {}
  /// (x_0, x_1, x_2); adjacency_0, adjacency_1, coadjacency_2; incidences B_01 (n0 × n1), B_12.
  std::vector<torch::Tensor> forward(const std::vector<torch::Tensor>& x,
                                     const nn::SparseOperator& adjacency_0,
                                     const nn::SparseOperator& adjacency_1,
                                     const nn::SparseOperator& coadjacency_2,
                                     const nn::SparseOperator& incidence_1,
                                     const nn::SparseOperator& incidence_2) {
    if (x.size() != 3) throw std::invalid_argument("HMC: expected x_0, x_1 and x_2");
    return run({{"x_0", x[0]}, {"x_1", x[1]}, {"x_2", x[2]}},
               {{"adjacency_0", adjacency_0},
                {"adjacency_1", adjacency_1},
                {"coadjacency_2", coadjacency_2},
                {"incidence_1", incidence_1},
                {"incidence_2", incidence_2}},
               {"x_0", "x_1", "x_2"});
  }
  HMCOptions options;
};
TORCH_MODULE(HMC);

}  // namespace topos::models
