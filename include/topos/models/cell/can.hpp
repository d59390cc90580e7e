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
// the edges (an adjacency holding each edge once). Pooling (TopoModelX's PoolLayer) is not
// implemented.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

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
  TORCH_ARG(nn::Update, att_activation) = nn::Update::leaky_relu;
  TORCH_ARG(double, att_negative_slope) = 0.2;
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool, att_lift) = true;
  TORCH_ARG(std::string, version) = "v1";
  TORCH_ARG(bool, share_weights) = false;
  TORCH_ARG(bool, add_self_loops) = true;
  TORCH_ARG(bool, topomodelx_compatible) = false;  ///< first layer without attention dropout
};

/// Multi-head attention over a neighbourhood's pattern (TopoModelX's MultiHeadCellAttention
/// and MultiHeadCellAttention_v2).
class CellAttentionImpl : public torch::nn::Module {
 public:
  CellAttentionImpl(std::int64_t in, std::int64_t out, std::int64_t heads, bool concat,
                    double dropout, const CANOptions& o)
      : out_(out),
        heads_(heads),
        concat_(concat),
        v2_(o.version() == "v2"),
        self_loops_(o.add_self_loops()),
        dropout_(dropout),
        act_(o.att_activation()),
        slope_(o.att_negative_slope()) {
    const auto c = out / heads;
    if (v2_) {
      lin_src = register_module("lin_src",
                                torch::nn::Linear(torch::nn::LinearOptions(in, out).bias(false)));
      lin_dst = o.share_weights()
                    ? lin_src
                    : torch::nn::Linear(torch::nn::LinearOptions(in, out).bias(false));
      register_module("lin_dst", lin_dst);
      att_weight = register_parameter("att_weight", torch::empty({1, heads, c}));
      torch::nn::init::xavier_uniform_(att_weight);
    } else {
      lin_src =
          register_module("lin", torch::nn::Linear(torch::nn::LinearOptions(in, out).bias(false)));
      att_src = register_parameter("att_weight_src", torch::empty({1, heads, c}));
      att_dst = register_parameter("att_weight_dst", torch::empty({1, heads, c}));
      torch::nn::init::xavier_uniform_(att_src);
      torch::nn::init::xavier_uniform_(att_dst);
    }
  }
  torch::Tensor forward(const torch::Tensor& x, const nn::SparseOperator& L) {
    const auto n = x.size(0), c = out_ / heads_;
    if (L.nnz() == 0 || !L.values.ne(0).any().item<bool>())
      return torch::zeros({n, concat_ ? out_ : c}, x.options());  // no neighbours at all
    const auto P = self_loops_ ? L.pattern_with_self_loops() : L.pattern();
    const auto row = P.row.to(x.device()), col = P.col.to(x.device());
    const auto xs = lin_src->forward(x).view({n, heads_, c});
    torch::Tensor score;  // nnz × heads
    if (v2_) {
      const auto xd = lin_dst->forward(x).view({n, heads_, c});
      const auto e =
          nn::apply_update(xs.index_select(0, col) + xd.index_select(0, row), act_, slope_);
      score = (e * att_weight).sum(-1);
    } else {
      const auto a_s = (xs * att_src).sum(-1), a_d = (xs * att_dst).sum(-1);  // n × heads
      score = nn::apply_update(a_s.index_select(0, col) + a_d.index_select(0, row), act_, slope_);
    }
    std::vector<torch::Tensor> per_head;
    for (std::int64_t h = 0; h < heads_; ++h) {
      auto alpha = torch::dropout(nn::row_softmax(P, score.select(1, h).contiguous()), dropout_,
                                  is_training());
      per_head.push_back(nn::spmm(P.with_values(alpha), xs.select(1, h).contiguous()));
    }
    return concat_ ? torch::cat(per_head, 1) : torch::stack(per_head, 0).mean(0);
  }
  torch::nn::Linear lin_src{nullptr}, lin_dst{nullptr};
  torch::Tensor att_src, att_dst, att_weight;

 private:
  std::int64_t out_, heads_;
  bool concat_, v2_, self_loops_;
  double dropout_;
  nn::Update act_;
  double slope_;
};
TORCH_MODULE(CellAttention);

class CANImpl : public torch::nn::Module {
 public:
  explicit CANImpl(const CANOptions& o) : options(o) {
    if (o.heads() < 1 || o.out_channels() % o.heads() != 0)
      throw std::invalid_argument("CAN: out_channels must be a multiple of heads (>= 1)");
    if (o.version() != "v1" && o.version() != "v2")
      throw std::invalid_argument("CAN: version must be v1 or v2");
    if (o.share_weights() && o.version() != "v2")
      throw std::invalid_argument("CAN: share_weights needs version v2");
    if (o.n_layers() < 1) throw std::invalid_argument("CAN: n_layers must be >= 1");
    if (o.dropout() < 0 || o.dropout() > 1)
      throw std::invalid_argument("CAN: dropout must be in [0, 1]");
    std::int64_t in = o.in_channels_1();
    if (o.att_lift()) {
      auto lift = nn::submodule_group(*this, "lift_layer");
      auto lifts = nn::submodule_group(*lift, "lifts");
      lift_ = lifts->register_parameter("att_parameter",
                                        torch::empty({2 * o.in_channels_0(), o.in_channels_0()}));
      nn::xavier_uniform(lift_, std::sqrt(2.0));
      in += o.in_channels_0();
    }
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      const auto layer_in = l == 0 ? in : o.out_channels();
      const double drop = l == 0 && o.topomodelx_compatible() ? 0.0 : o.dropout();
      auto m = std::make_shared<torch::nn::Module>();
      Layer layer{m->register_module("lower_att", CellAttention(layer_in, o.out_channels(),
                                                                o.heads(), o.concat(), drop, o)),
                  m->register_module("upper_att", CellAttention(layer_in, o.out_channels(),
                                                                o.heads(), o.concat(), drop, o)),
                  nullptr};
      if (o.skip_connection())
        layer.skip = m->register_module(
            "lin", torch::nn::Linear(
                       torch::nn::LinearOptions(
                           layer_in, o.concat() ? o.out_channels() : o.out_channels() / o.heads())
                           .bias(false)));
      layers_.push_back(layer);
      list->push_back(m);
    }
  }
  /// Node and edge features, the node adjacency (for the lift), L_1↓ and L_1↑. Returns the edge
  /// features.
  torch::Tensor forward(const torch::Tensor& x_0, torch::Tensor x_1,
                        const nn::SparseOperator& adjacency_0,
                        const nn::SparseOperator& down_laplacian_1,
                        const nn::SparseOperator& up_laplacian_1) {
    if (lift_.defined()) {
      if (adjacency_0.nnz() != x_1.size(0))
        throw std::invalid_argument("CAN: att_lift makes one edge row per entry of adjacency_0 (" +
                                    std::to_string(adjacency_0.nnz()) + "), but x_1 has " +
                                    std::to_string(x_1.size(0)) +
                                    " rows (pass an adjacency that holds each edge once)");
      const auto u = adjacency_0.row.to(x_0.device()), v = adjacency_0.col.to(x_0.device());
      auto lifted = torch::relu(
          torch::cat({x_0.index_select(0, u), x_0.index_select(0, v)}, 1).matmul(lift_));
      lifted = torch::dropout(lifted, 0.5, is_training());
      x_1 = torch::cat({lifted, x_1}, 1);
    }
    for (auto& l : layers_) {
      std::vector<torch::Tensor> m{l.lower->forward(x_1, down_laplacian_1),
                                   l.upper->forward(x_1, up_laplacian_1)};
      if (l.skip) m.push_back(l.skip->forward(x_1) * (1 + 1e-6));
      x_1 = torch::dropout(nn::aggregate_messages(m, nn::Aggr::sum, nn::Update::relu), 0.5,
                           is_training());
    }
    return x_1;
  }
  CANOptions options;

 private:
  struct Layer {
    CellAttention lower, upper;
    torch::nn::Linear skip;
  };
  torch::Tensor lift_;
  std::vector<Layer> layers_;
};
TORCH_MODULE(CAN);

}  // namespace topos::models
