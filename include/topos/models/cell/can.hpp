// topos/models/cell/can.hpp
// CAN (Giusti et al., "Cell attention networks", 2022; TopoModelX CAN): on the edges of a cell
// complex, per layer multi-head attention over the lower and over the upper neighbourhood
// (the sparsity patterns of L_1↓ and L_1↑ with self loops; the Laplacians' values are not
// used), plus a linear skip connection, summed, then relu. Attention "v1" (GAT): per head
// softmax over a target's entries of act(a_src·W x_j + a_dst·W x_i), messages W x_j; "v2"
// (GATv2): act(W_s x_j + W_d x_i)·a, messages W_s x_j. Heads concatenated or averaged.
// Optionally the edge features are first extended by a lift of the node features
// (att_lift: relu([x_u ‖ x_v] P) per entry of the node adjacency, TopoModelX's
// MultiHeadLiftLayer with in_channels_0 heads). Parameters as TopoModelX names them
// (layers.<i>.lower_att.lin.weight, .att_weight_src/.att_weight_dst or .lin_src/.lin_dst/
// .att_weight, layers.<i>.lin.weight, lift_layer.lifts.att_parameter).
// As in TopoModelX: the attention activation is LeakyReLU(0.2) unless one is named; the first
// layer has no attention dropout (the compatible mode; the default gives every layer `dropout`);
// the lift makes one row per stored entry of the adjacency it gets, which must be as many as
// the edges (an adjacency holding each edge once). With `pooling`, TopoModelX's PoolLayer follows
// every layer but the first (the edges of highest score kept, the Laplacians restricted to them),
// and the schedule runs layer by layer. Written as an operator schedule (can_schedule), its
// attention CAN's own operation (CanAttention).
#pragma once

#include "topos/models/query_attention.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <cmath>
#include <string>
#include <utility>
#include <vector>

namespace topos::models {

/// CAN's multi-head attention, its own operation through the operator schedule's extension
/// point: messages x (the term's features, heads in column blocks) over A (`op`), per head a
/// per-target softmax of the scores, with dropout on the weights in training, times A's values;
/// the heads concatenated or averaged. The scores of entry (i, j) against the `queries` cochain
/// q: GAT's act(a_src·x_j + a_dst·q_i), a_src and a_dst at `path`.att_weight_src and
/// .att_weight_dst, or GATv2's (`v2`) a·act(x_j + q_i), a at `path`.att_weight; each of shape
/// 1 × heads × (channels / heads), Glorot with gain 1 (TopoModelX's CAN).
struct CanAttention : nn::Operation {
  CanAttention(std::string op, std::string path, nn::CochainKey queries, std::int64_t heads)
      : op(std::move(op)), path(std::move(path)), queries(std::move(queries)), heads(heads) {}
  std::string op, path;
  nn::CochainKey queries;
  std::int64_t heads;
  bool concat = true;
  bool v2 = false;
  double dropout = 0;
  nn::Activation activation = nn::Activation::leaky_relu;
  double negative_slope = 0.2;

  std::string str(const std::string& x) const override {
    return std::string(v2 ? "can_attend_v2[" : "can_attend[") + path +
           (heads > 1 ? " ×" + std::to_string(heads) : "") + "]" + op + "·" + x;
  }
  nn::TermShape infer(nn::BuildContext& ctx, nn::TermShape x) const override {
    const auto dst = ctx.operator_from(op, x.rank).second;
    const auto fail = [&](const std::string& why) {
      ctx.fail("CAN attention over '" + op + "' " + why);
    };
    const auto ck = x.channels,
               cq = query_width(ctx, queries, dst, "CAN attention over '" + op + "'");
    if (heads < 1 || ck % heads || cq % heads)
      fail("with " + std::to_string(heads) + " heads: the messages (" + std::to_string(ck) +
           ") and queries (" + std::to_string(cq) + ") need channels divisible by the heads");
    if (v2 && cq != ck)
      fail("(GATv2) needs queries as wide as its keys, got " + std::to_string(cq) + " and " +
           std::to_string(ck));
    if (!(dropout >= 0 && dropout <= 1)) fail("needs a dropout rate in [0, 1]");
    const auto glorot = nn::ParameterInit::glorot(1.0);
    if (v2) {
      ctx.parameter(path + ".att_weight", {1, heads, ck / heads}, glorot);
    } else {
      ctx.parameter(path + ".att_weight_src", {1, heads, ck / heads}, glorot);
      ctx.parameter(path + ".att_weight_dst", {1, heads, cq / heads}, glorot);
    }
    return {dst, concat ? ck : ck / heads};
  }
  torch::Tensor forward(nn::RunContext& ctx, const torch::Tensor& x) const override {
    const auto& A = ctx.op(op);
    const auto& q = query_rows(ctx, A, x, queries, op);
    if (!v2)  // GATConv's scores: per source and target cell, then per entry in the kernel
      return nn::multi_head_attention_from_cells(
          A, nn::head_scores(x, ctx.parameter(path + ".att_weight_src").reshape({-1}), heads),
          nn::head_scores(q, ctx.parameter(path + ".att_weight_dst").reshape({-1}), heads), x,
          concat, activation, negative_slope, nn::AttentionNorm::softmax, dropout,
          ctx.is_training(), ctx.fast_paths().fuse_attention());
    // GATv2's: the activation of the summed features, then per head <e, a> (nnz × heads).
    const auto a = ctx.parameter(path + ".att_weight").reshape({-1});
    const auto e = nn::apply_activation(
        x.index_select(0, A.col.to(x.device())) + q.index_select(0, A.row.to(x.device())),
        activation, negative_slope);
    const auto raw = (e.reshape({e.size(0), heads, -1}) * a.reshape({1, heads, -1})).sum(-1);
    return nn::multi_head_attention(A, raw, x, concat, nn::Activation::none, negative_slope,
                                    nn::AttentionNorm::softmax, dropout, ctx.is_training());
  }
};

struct CANOptions {
  CANOptions(std::int64_t in_channels_0, std::int64_t in_channels_1, std::int64_t out_channels)
      : in_channels_0_(in_channels_0), in_channels_1_(in_channels_1), out_channels_(out_channels) {}
  TORCH_ARG(std::int64_t, in_channels_0);
  TORCH_ARG(std::int64_t, in_channels_1);
  TORCH_ARG(std::int64_t, out_channels);
  TORCH_ARG(double, dropout) = 0.5;
  TORCH_ARG(std::int64_t, heads) = 2;
  TORCH_ARG(bool, concat) = true;
  TORCH_ARG(bool, skip_connection) = true;
  TORCH_ARG(nn::Activation, att_activation) = nn::Activation::leaky_relu;
  TORCH_ARG(double, att_negative_slope) = 0.2;
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool, att_lift) = true;
  TORCH_ARG(std::string, version) = "v1";
  TORCH_ARG(bool, share_weights) = false;
  TORCH_ARG(bool, add_self_loops) = true;
  TORCH_ARG(bool, topomodelx_compatible) = false;  ///< first layer without attention dropout
  /// TopoModelX's PoolLayer after every layer but the first: keep the int(k_pool · n) edges of
  /// highest score x·a, scaled by sigmoid(score), and restrict L_1↓, L_1↑ to them.
  TORCH_ARG(bool, pooling) = false;
  TORCH_ARG(double, k_pool) = 0.5;
};

/// Where layer l sits in TopoModelX's "layers" list: with pooling each layer after the first is
/// followed by its PoolLayer (layers.0 CAN, layers.1 CAN, layers.2 pool, layers.3 CAN, ...).
inline int can_layer_index(const CANOptions& o, int l) {
  return o.pooling() && l > 0 ? 2 * l - 1 : l;
}

/// The schedule: the lift (the node features of each adjacency entry's two ends side by side,
/// "lift_source"/"lift_target" selecting them), then per layer the attention's linear maps of
/// x_1 (states "lower", "upper" and, for v2, their "_dst" maps) and one step summing the
/// multi-head attention over "lower" and "upper" (the neighbourhoods' patterns) and the skip.
inline nn::OperatorSchedule can_schedule(const CANOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  if (o.heads() < 1 || o.out_channels() % o.heads() != 0)
    throw std::invalid_argument("CAN: out_channels must be a multiple of heads (>= 1)");
  if (o.version() != "v1" && o.version() != "v2")
    throw std::invalid_argument("CAN: version must be v1 or v2");
  if (o.share_weights() && o.version() != "v2")
    throw std::invalid_argument("CAN: share_weights needs version v2");
  if (o.n_layers() < 1) throw std::invalid_argument("CAN: n_layers must be >= 1");
  if (o.dropout() < 0 || o.dropout() > 1)
    throw std::invalid_argument("CAN: dropout must be in [0, 1]");
  if (o.pooling() && !(o.k_pool() > 0 && o.k_pool() <= 1))
    throw std::invalid_argument("CAN: k_pool must be in (0, 1]");
  const bool v2 = o.version() == "v2";
  const auto H = o.heads(), out = o.out_channels(), c = out / H;
  nn::OperatorSchedule s;
  s.input("x_1", 1, o.in_channels_1())
      .operator_input("lower", 1, 1)
      .operator_input("upper", 1, 1)
      .output("x_1", 1);
  s.layer("layer 0");  // the lift, when there is one, runs with the first layer
  if (o.att_lift()) {
    const auto c0 = o.in_channels_0();
    s.input("x_0", 0, c0).operator_input("lift_source", 0, 1).operator_input("lift_target", 0, 1);
    s.step(into(1, "lift")
               .concat(from(0).via("lift_source"), from(0).via("lift_target"))
               .weight("lift_layer.lifts.att_parameter", c0, std::sqrt(2.0))
               .act(Activation::relu)
               .dropout(0.5));
    s.step(into(1).concat(from(1, "lift"), from(1)));
  }
  for (int l = 0; l < o.n_layers(); ++l) {
    if (l > 0) s.layer("layer " + std::to_string(l));
    const auto p = "layers." + std::to_string(can_layer_index(o, l)) + ".";
    std::vector<nn::OperatorStep> maps;
    std::vector<Term> terms;
    for (const std::string side : {"lower", "upper"}) {
      const auto q = p + side + "_att";
      const auto queries = v2 && !o.share_weights() ? side + "_dst" : side;
      CanAttention att(side, q, nn::CochainKey{1, queries}, H);
      att.concat = o.concat();
      att.v2 = v2;
      att.dropout = l == 0 && o.topomodelx_compatible() ? 0.0 : o.dropout();
      att.activation = o.att_activation();
      att.negative_slope = o.att_negative_slope();
      if (v2) {
        maps.push_back(into(1, side).sum(from(1).linear(q + ".lin_src", out, false)));
        if (!o.share_weights())
          maps.push_back(into(1, side + "_dst").sum(from(1).linear(q + ".lin_dst", out, false)));
      } else {
        maps.push_back(into(1, side).sum(from(1).linear(q + ".lin", out, false)));
      }
      terms.push_back(from(1, side).apply(std::move(att)));
    }
    if (o.skip_connection())
      terms.push_back(from(1).linear(p + "lin", o.concat() ? out : c, false).scale(1 + 1e-6));
    s.parallel(std::move(maps));
    s.step(into(1).sum(std::move(terms)).act(Activation::relu).dropout(0.5).named(p + "update"));
    if (o.pooling() && l > 0)
      s.parameter("layers." + std::to_string(2 * l) + ".att_pool", {o.concat() ? out : c, 1},
                  std::sqrt(2.0));
  }
  return s;
}

class CANImpl : public nn::Cloneable<CANImpl, nn::OperatorNetworkImpl> {
 public:
  explicit CANImpl(const CANOptions& o) : Cloneable(can_schedule(o)), options(o) {
    // TopoModelX's shared weights: lin_dst is lin_src, so its state_dict names both.
    if (o.share_weights())
      for (int l = 0; l < o.n_layers(); ++l)
        for (const char* side : {"lower", "upper"}) {
          auto att = named_modules(
              "", false)["layers." + std::to_string(can_layer_index(o, l)) + "." + side + "_att"];
          att->register_module("lin_dst", att->named_children()["lin_src"]);
        }
  }
  /// Node and edge features, the node adjacency (for the lift), L_1↓ and L_1↑. Returns the edge
  /// features.
  torch::Tensor forward(const torch::Tensor& x_0, const torch::Tensor& x_1,
                        const nn::SparseOperator& adjacency_0,
                        const nn::SparseOperator& down_laplacian_1,
                        const nn::SparseOperator& up_laplacian_1) {
    std::map<std::string, nn::SparseOperator> ops{{"lower", neighbourhood(down_laplacian_1)},
                                                  {"upper", neighbourhood(up_laplacian_1)}};
    if (options.att_lift()) {
      if (adjacency_0.nnz() != x_1.size(0))
        throw std::invalid_argument("CAN: att_lift makes one edge row per entry of adjacency_0 (" +
                                    std::to_string(adjacency_0.nnz()) + "), but x_1 has " +
                                    std::to_string(x_1.size(0)) +
                                    " rows (pass an adjacency that holds each edge once)");
      ops["lift_source"] = nn::SparseOperator::selection(adjacency_0.row, x_0.size(0));
      ops["lift_target"] = nn::SparseOperator::selection(adjacency_0.col, x_0.size(0));
    }
    std::map<std::string, torch::Tensor> in{{"x_1", x_1}};
    if (options.att_lift()) in["x_0"] = x_0;  // read by the lift only
    if (!options.pooling()) return run(in, ops, {"x_1"})[0];
    // With pooling the schedule runs layer by layer: after each layer but the first, the edges of
    // highest score are kept and the Laplacians restricted to them.
    auto h = input_cochains(in);
    auto L_down = down_laplacian_1, L_up = up_laplacian_1;
    for (int l = 0; l < options.n_layers(); ++l) {
      run_layer(h, ops, "layer " + std::to_string(l));
      if (l == 0) continue;
      const auto& x = h.at(1);
      const auto score = x.matmul(parameter("layers." + std::to_string(2 * l) + ".att_pool"));
      const auto keep =
          static_cast<std::int64_t>(options.k_pool() * static_cast<double>(x.size(0)));
      if (keep < 1)
        throw std::invalid_argument("CAN: pooling keeps int(" + std::to_string(options.k_pool()) +
                                    " * " + std::to_string(x.size(0)) + ") = 0 edges");
      const auto top = std::get<1>(torch::topk(score.view({-1}), keep));
      h.set(1, "", x.index_select(0, top) * torch::sigmoid(score).index_select(0, top));
      L_down = L_down.principal_submatrix(top), L_up = L_up.principal_submatrix(top);
      ops["lower"] = neighbourhood(L_down), ops["upper"] = neighbourhood(L_up);
    }
    return h.at(1);
  }
  CANOptions options;

 private:
  /// The attention's pattern: L's with self loops (or without); with no nonzero entry at all,
  /// none (no neighbours: the messages are zeros, self loops or not).
  nn::SparseOperator neighbourhood(const nn::SparseOperator& L) const {
    if (L.nnz() == 0 || !L.values.ne(0).any().item<bool>())
      return nn::SparseOperator::from_sorted(L.rows, L.cols, {}, {},
                                             torch::empty({0}, L.values.options()));
    return options.add_self_loops() ? L.pattern_with_self_loops() : L.pattern();
  }
};
TORCH_MODULE(CAN);

}  // namespace topos::models
