// topos/models/simplicial/san.hpp
// SAN (Giusti et al., "Simplicial attention neural networks", 2022; TopoModelX SAN) on edge
// features: per layer, attention-weighted filters over the lower and upper Laplacians' patterns
// (Σ_p A^(p+1) x W_p with A the per-target softmax of elu(a·[x W_j || x W_i]), the filters'
// outputs side by side in the score) plus a harmonic filter (I - εL)^k x W with
// L = L_up + L_down. Written as an operator schedule (san_schedule): the filter banks as head
// weights, their attention and the harmonic filter as SAN's own operations (SanFilterAttention,
// AffinePower). Everything is sparse
// products, the filter bank's powers in Horner form (P products for P filters): TopoModelX forms
// the attention matrix densely and the harmonic projection as a dense n × n matrix power.
// Parameters as TopoModelX's (layers.<i>.conv_down.weight (filters × in × out), .att_weight
// (2·out·filters), layers.<i>.conv_harmonic.weight).
#pragma once

#include "topos/models/query_attention.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace topos::models {

struct SANOptions {
  SANOptions(std::int64_t in, std::int64_t hidden) : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(std::int64_t, out_channels) = 0;  ///< 0: hidden_channels
  TORCH_ARG(int, n_filters) = 2;
  TORCH_ARG(int, order_harmonic) = 5;
  TORCH_ARG(double, epsilon_harmonic) = 0.1;
  TORCH_ARG(int, n_layers) = 2;
};

/// (a I + b Σ_i A_i)^k x by k rounds of sparse products, the sum and its power never formed (SAN's
/// harmonic filter (I - ε(L↑ + L↓))^k; nn::apply_affine_power), the A_i square and not trained.
/// SAN's own operation, through the operator schedule's extension point.
struct AffinePower : nn::Operation {
  AffinePower(std::vector<std::string> operators, int k, double a, double b)
      : operators(std::move(operators)), k(k), a(a), b(b) {}
  std::vector<std::string> operators;
  int k;
  double a, b;
  std::string str(const std::string& x) const override {
    std::ostringstream o;
    o << "(" << a << " I + " << b << " (";
    for (std::size_t i = 0; i < operators.size(); ++i) o << (i ? " + " : "") << operators[i];
    o << "))^" << k << "·" << x;
    return o.str();
  }
  nn::TermShape infer(nn::BuildContext& ctx, nn::TermShape x) const override {
    if (operators.empty()) ctx.fail("an affine power needs an operator");
    if (k < 0) ctx.fail("an affine power's exponent is negative");
    for (const auto& op : operators) {
      const auto [src, dst] = ctx.operator_ranks(op);
      if (src != x.rank || dst != x.rank)
        ctx.fail("the affine power needs operators from rank " + std::to_string(x.rank) +
                 " to itself, '" + op + "' maps " + std::to_string(src) + " -> " +
                 std::to_string(dst));
    }
    return x;
  }
  torch::Tensor forward(nn::RunContext& ctx, const torch::Tensor& x) const override {
    std::vector<nn::SparseOperator> terms;
    for (const auto& op : operators) {
      terms.push_back(ctx.op(op));
      if (terms.back().cols != x.size(0))
        ctx.fail("operator '" + op + "' has " + std::to_string(terms.back().cols) +
                 " columns but the cochain it is applied to has " + std::to_string(x.size(0)) +
                 " rows");
    }
    return nn::apply_affine_power(terms, x, k, a, b);
  }
};

/// SAN's attention over a filter bank, its own operation through the operator schedule's
/// extension point: the messages x are `filters` slices of equal width (x W_0 | ... | x W_(P-1),
/// from head_weights); one operator W, A's entries (i, j) weighted by the per-target softmax of
/// elu(a_s·x_j + a_t·q_i) (all the slices side by side, q the `queries` cochain; a at `param`, of
/// x's plus q's widths) times A's values; then Σ_p W^(p+1) x_p, in Horner form:
/// W(x_0 + W(x_1 + ... W x_(P-1))), P products.
struct SanFilterAttention : nn::Operation {
  SanFilterAttention(std::string op, std::string param, nn::CochainKey queries,
                     std::int64_t filters)
      : op(std::move(op)), param(std::move(param)), queries(std::move(queries)), filters(filters) {}
  std::string op, param;
  nn::CochainKey queries;
  std::int64_t filters;

  std::string str(const std::string& x) const override {
    return "san_attend[" + param + " ×" + std::to_string(filters) + " filters]" + op + "·" + x;
  }
  nn::TermShape infer(nn::BuildContext& ctx, nn::TermShape x) const override {
    const auto dst = ctx.operator_from(op, x.rank).second;
    const auto fail = [&](const std::string& why) {
      ctx.fail("SAN attention over '" + op + "' " + why);
    };
    const auto cq = query_width(ctx, queries, dst, "SAN attention over '" + op + "'");
    if (filters < 1 || x.channels % filters)
      fail("with " + std::to_string(filters) + " filters needs messages (" +
           std::to_string(x.channels) + " channels) of whole filters");
    ctx.parameter(param, {x.channels + cq}, nn::ParameterInit::glorot(1.414));
    return {dst, x.channels / filters};
  }
  torch::Tensor forward(nn::RunContext& ctx, const torch::Tensor& x) const override {
    const auto& A = ctx.op(op);
    const auto& q = query_rows(ctx, A, x, queries, op);
    const auto a = ctx.parameter(param).reshape({-1});
    const auto ck = x.size(1);
    const auto raw = nn::entry_scores(A, nn::head_scores(x, a.narrow(0, 0, ck)),
                                      nn::head_scores(q, a.narrow(0, ck, a.size(0) - ck)));
    const auto W =
        nn::attention_operator(A, raw, nn::Activation::elu, 0.2, nn::AttentionNorm::softmax);
    // The slices by one split: its backward writes every slice's gradient into one matrix, where
    // a narrow per slice allocates a zero-filled one each.
    const auto x_p = x.split(ck / filters, 1);
    auto z = x_p[static_cast<std::size_t>(filters - 1)].contiguous();
    for (auto p = filters - 2; p >= 0; --p) z = x_p[static_cast<std::size_t>(p)] + nn::spmm(W, z);
    return nn::spmm(W, z);
  }
};

/// The schedule: per layer the two filter banks' maps (states "down", "up"), then one step
/// summing the attention over "lower" and "upper" (the Laplacians' patterns) and the harmonic
/// filter over "laplacian_up" and "laplacian_down".
inline nn::OperatorSchedule san_schedule(const SANOptions& o) {
  using namespace nn::ops;
  if (o.in_channels() <= 0 || o.hidden_channels() <= 0 || o.out_channels() < 0)
    throw std::invalid_argument("SAN: the channels must be positive");
  if (o.n_filters() < 1 || o.order_harmonic() < 0 || o.n_layers() < 1)
    throw std::invalid_argument("SAN: n_filters and n_layers must be >= 1, order_harmonic >= 0");
  const auto out = o.out_channels() > 0 ? o.out_channels() : o.hidden_channels();
  const int P = o.n_filters();
  nn::OperatorSchedule s;
  s.input("x_1", 1, o.in_channels())
      .operator_input("lower", 1, 1)
      .operator_input("upper", 1, 1)
      .operator_input("laplacian_down", 1, 1)
      .operator_input("laplacian_up", 1, 1)
      .output("x_1", 1);
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    const auto c = l + 1 == o.n_layers() ? out : o.hidden_channels();
    auto bank = [&](const std::string& side, const std::string& op) {
      return from(1, side).apply(
          SanFilterAttention(op, p + "conv_" + side + ".att_weight", {1, side}, P));
    };
    s.parallel({into(1, "down").sum(from(1).head_weights(p + "conv_down.weight", P, c)),
                into(1, "up").sum(from(1).head_weights(p + "conv_up.weight", P, c))});
    s.step(into(1)
               .sum(bank("down", "lower"), bank("up", "upper"),
                    from(1)
                        .conv(p + "conv_harmonic", c)
                        .apply(AffinePower({"laplacian_up", "laplacian_down"}, o.order_harmonic(),
                                           1.0, -o.epsilon_harmonic())))
               .named(p + "filters"));
  }
  return s;
}

class SANImpl : public nn::Cloneable<SANImpl, nn::OperatorNetworkImpl> {
 public:
  explicit SANImpl(const SANOptions& o) : Cloneable(san_schedule(o)), options(o) {}
  torch::Tensor forward(const torch::Tensor& x, const nn::SparseOperator& laplacian_up,
                        const nn::SparseOperator& laplacian_down) {
    return run({{"x_1", x}},
               {{"lower", laplacian_down.pattern()},
                {"upper", laplacian_up.pattern()},
                {"laplacian_down", laplacian_down},
                {"laplacian_up", laplacian_up}},
               {"x_1"})[0];
  }
  SANOptions options;
};
TORCH_MODULE(SAN);

}  // namespace topos::models
