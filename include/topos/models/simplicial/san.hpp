// topos/models/simplicial/san.hpp
// SAN (Giusti et al., "Simplicial attention neural networks", 2022; TopoModelX SAN) on edge
// features: per layer, attention-weighted filters over the lower and upper Laplacians' patterns
// (Σ_p A^(p+1) x W_p with A the per-target softmax of elu(a·[x W_j || x W_i]), the filters'
// outputs side by side in the score) plus a harmonic filter (I - εL)^k x W with
// L = L_up + L_down. Written as an operator schedule (san_schedule): the filter banks as head
// weights, attention with `filters`, the harmonic filter as an affine power. Everything is sparse
// products, the filter bank's powers in Horner form (P products for P filters): TopoModelX forms
// the attention matrix densely and the harmonic projection as a dense n × n matrix power.
// Parameters as TopoModelX's (layers.<i>.conv_down.weight (filters × in × out), .att_weight
// (2·out·filters), layers.<i>.conv_harmonic.weight).
#pragma once

#include "topos/nn/operator_schedule.hpp"

#include <sstream>

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

/// The schedule: per layer the two filter banks' maps (states "down", "up"), then one step
/// summing the attention over "lower" and "upper" (the Laplacians' patterns) and the harmonic
/// filter over "laplacian_up" and "laplacian_down".
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
      const auto path = p + "conv_" + side;
      return std::move(from(1, side).attend(op, nn::AttendOptions(path + ".att_weight")
                                                    .activation(nn::Update::elu)
                                                    .norm(nn::AttentionNorm::softmax)
                                                    .queries(nn::CochainKey{1, side})
                                                    .filters(P)));
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
