// topos/models/hypergraph/unigcnii.hpp
// UniGCNII (Huang & Yang, "UniGNN", 2021; TopoModelX UniGCNII): a linear map and relu, then per
// layer the two-stage message x_1 = Bᵀ x_0, x̂_0 = D_v^-1/2 B D_e^-1/2 x_1 (d_e: the mean degree
// of a hyperedge's nodes), GCNII's initial residual and identity mapping, relu. Degrees are
// vectors and the products sparse (TopoModelX uses dense diagonal matrices).
// TopoModelX ignores `beta` (β_l = log(α/(l+1) + 1)); the default here is GCNII's
// β_l = log(β/(l+1) + 1); topomodelx_compatible(true) gives TopoModelX's numbers. Written as an
// operator schedule (unigcnii_schedule).
#pragma once

#include "topos/nn/kernels.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <cmath>

namespace topos::models {

struct UniGCNIIOptions {
  UniGCNIIOptions(std::int64_t in, std::int64_t hidden)
      : in_channels_(in), hidden_channels_(hidden) {}
  TORCH_ARG(std::int64_t, in_channels);
  TORCH_ARG(std::int64_t, hidden_channels);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(double, alpha) = 0.5;
  TORCH_ARG(double, beta) = 0.5;
  TORCH_ARG(double, input_drop) = 0.2;
  TORCH_ARG(double, layer_drop) = 0.2;
  TORCH_ARG(bool, use_norm) = false;
  TORCH_ARG(bool, topomodelx_compatible) = false;
};

namespace detail {
/// GCNII's update x̃ Mᵀ, x̃ = (1-α) x + α s, M = β W + (1-β) I, as one autograd node: the same
/// tensor operations as written out (forward) and as LibTorch's nodes for them would give
/// (backward), without the eight nodes and their saved tensors. Its backward is linear_act's
/// (LinearFunction::gradients, on the library its forward ran on), then dx = (1-α) dx̃, ds = α dx̃,
/// dW = β dM.
struct InitialResidualFunction : torch::autograd::Function<InitialResidualFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               const torch::Tensor& s, const torch::Tensor& W, double alpha,
                               double beta) {
    const auto mixed = (1 - alpha) * x + alpha * s;
    const auto M = beta * W + (1 - beta) * torch::eye(W.size(0), W.options());
    // linear_act's forward (its kernel choice; no graph is recorded inside a Function).
    const auto [y, path] = nn::detail::LinearFunction::product(mixed, M, {}, nn::Epilogue::none);
    ctx->save_for_backward({mixed, M});
    ctx->saved_data["alpha"] = alpha;
    ctx->saved_data["beta"] = beta;
    ctx->saved_data["path"] = static_cast<std::int64_t>(path);
    return y;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &mixed = saved[0], &M = saved[1];
    const double alpha = ctx->saved_data["alpha"].toDouble(),
                 beta = ctx->saved_data["beta"].toDouble();
    const bool want_x = ctx->needs_input_grad(0) || ctx->needs_input_grad(1),
               want_W = ctx->needs_input_grad(2);
    const auto g = grads[0].contiguous();
    // linear_act's backward on the library its forward ran on, no activation.
    const auto d = nn::detail::LinearFunction::gradients(
        mixed, M, torch::Tensor(), g, nn::Epilogue::none,
        static_cast<nn::detail::ProductPath>(ctx->saved_data["path"].toInt()), want_x, want_W,
        false);
    const auto &dmixed = d[0], &dM = d[1];
    torch::Tensor dx, ds, dW;
    if (ctx->needs_input_grad(0)) dx = dmixed * (1 - alpha);
    if (ctx->needs_input_grad(1)) ds = dmixed * alpha;
    if (want_W) dW = dM * beta;
    return {dx, ds, dW, {}, {}};
  }
};
}  // namespace detail

/// The schedule: a linear map, then per layer the two-stage message and GCNII's update.
/// GCNII's initial residual and identity mapping: x̃ = (1-α) x + α skip, then
/// (1-β) x̃ + β Linear(x̃) with the bias-free Linear at `path`. UniGCNII's own operation, through
/// the operator schedule's extension point.
struct InitialResidual : nn::Operation {
  InitialResidual(nn::CochainKey skip, double alpha, double beta, std::string path)
      : skip(std::move(skip)), alpha(alpha), beta(beta), path(std::move(path)) {}
  nn::CochainKey skip;
  double alpha, beta;
  std::string path;
  std::string str(const std::string& x) const override {
    return "residual(" + x + ", " + skip.str() + ", " + path + ")";
  }
  nn::TermShape infer(nn::BuildContext& ctx, nn::TermShape x) const override {
    const auto w = ctx.cochain_width(skip);
    if (skip.rank != x.rank || w != x.channels)
      ctx.fail("residual cochain " + skip.str() + " of rank " + std::to_string(skip.rank) +
               " and " + std::to_string(w) + " channels added to rank " + std::to_string(x.rank) +
               " and " + std::to_string(x.channels));
    ctx.parameter(path + ".weight", {x.channels, x.channels}, nn::ParameterInit::linear_weight());
    return x;
  }
  torch::Tensor forward(nn::RunContext& ctx, const torch::Tensor& x) const override {
    const auto& s = ctx.cochain(skip);
    const auto& W = ctx.parameter(path + ".weight");
    // (1-β) x̃ + β x̃ Wᵀ as one product with (1-β) I + β W: one pass over the rows, not three;
    // with the mixing, one autograd node where linear_act takes the product (CPU, float).
    if (!fused_residual || !x.device().is_cpu() || x.dim() != 2 || s.sizes() != x.sizes() ||
        x.scalar_type() != torch::kFloat || s.scalar_type() != x.scalar_type() ||
        W.scalar_type() != x.scalar_type()) {
      const auto mixed = (1 - alpha) * x + alpha * s;
      return nn::linear_act(mixed, beta * W + (1 - beta) * torch::eye(W.size(0), W.options()), {});
    }
    return detail::InitialResidualFunction::apply(x, s, W, alpha, beta);
  }
  /// Its product by (1-β) I + β W: 2·rows·in·out (the mixing is not counted, as activations
  /// are not).
  nn::OperationCost cost(const nn::CostContext& c) const override {
    return nn::OperationCost::dense(c.rows, c.x.channels, c.y.channels);
  }
  /// One autograd node (InitialResidualFunction) where it applies; false: the operations
  /// written out, each LibTorch's node (what the tests compare it with).
  bool fused_residual = true;
};

inline nn::OperatorSchedule unigcnii_schedule(const UniGCNIIOptions& o) {
  using namespace nn::ops;
  using nn::Activation;
  const auto h = o.hidden_channels();
  nn::OperatorSchedule s;
  s.input("x_0", 0, o.in_channels())
      .operator_input("incidence_1", 1, 0)        // B: nodes × hyperedges
      .operator_input("incidence_1_norm", 1, 0);  // D_v^-1/2 B D_e^-1/2
  s.step(into(0)
             .sum(from(0).dropout(o.input_drop()).linear("initial_linear_layer", h))
             .act(Activation::relu));
  s.step(into(0, "initial").sum(from(0)));
  for (int l = 0; l < o.n_layers(); ++l) {
    const double beta = std::log((o.topomodelx_compatible() ? o.alpha() : o.beta()) / (l + 1) + 1);
    s.step(into(1).sum(from(0).via_t("incidence_1")));
    auto update = into(0).sum(from(1).via("incidence_1_norm"));
    update.apply(InitialResidual({0, "initial"}, o.alpha(), beta,
                                 "layers." + std::to_string(l) + ".linear"));
    if (o.use_norm()) update.unit_rows();
    s.step(std::move(update.dropout(o.layer_drop()).act(Activation::relu)));
  }
  if (o.n_layers() == 0) s.step(into(1).sum(from(0).via_t("incidence_1")));
  s.output("x_0", 0).output("x_1", 1);
  return s;
}

class UniGCNIIImpl : public nn::Cloneable<UniGCNIIImpl, nn::OperatorNetworkImpl> {
 public:
  explicit UniGCNIIImpl(const UniGCNIIOptions& o) : Cloneable(unigcnii_schedule(o)), options(o) {}
  /// x_0 (nodes) and the node × hyperedge incidence; returns (x_0, x_1 of the last layer).
  std::vector<torch::Tensor> forward(const torch::Tensor& x0,
                                     const nn::SparseOperator& incidence_1) {
    const auto dv = incidence_1.row_sums();
    if ((dv <= 0).any().item<bool>())
      throw std::invalid_argument("UniGCNII: every node must be in a hyperedge (add self-loops)");
    const auto de = incidence_1.scaled(dv).col_sums() / incidence_1.col_sums();
    if (!(de > 0).all().item<bool>())
      throw std::invalid_argument("UniGCNII: every hyperedge must contain a node");
    return run({{"x_0", x0}},
               {{"incidence_1", incidence_1},
                {"incidence_1_norm", incidence_1.scaled(dv.rsqrt(), de.rsqrt())}},
               {"x_0", "x_1"});
  }
  UniGCNIIOptions options;
};
TORCH_MODULE(UniGCNII);

}  // namespace topos::models
