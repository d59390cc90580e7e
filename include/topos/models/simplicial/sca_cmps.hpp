// topos/models/simplicial/sca_cmps.hpp
// SCA with CMPS (Hajij et al., "Simplicial complex representation learning", 2022; TopoModelX
// SCACMPS): ranks 1 .. complex_dim-1 in turn, each from its own features over the lower
// Laplacian and from the rank below (already updated) over B_rᵀ; each message x is reweighted
// per cell by σ(<relu(Σ_cells x), x_i>) (intra-neighbourhood aggregation), the two averaged,
// then relu. Rank 0 passes through. Parameters layers.<i>.lap_layers.<r-1>.weight (and
// att_weight with att) and layers.<i>.inc_layers.<r-1>.*. Written as an operator schedule
// (sca_cmps_schedule): one step per rank, in order, so each sees the rank below updated.
// With attention TopoModelX scores B_rᵀ's entries against the source rank's features on both
// sides (its Conv's x_target defaults to x_source, which indexes rank r-1's rows by rank r's
// cells, out of range as soon as rank r has more cells); the default scores the target rank's
// own features, the compatible mode TopoModelX's.
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct SCACMPSOptions {
  SCACMPSOptions(std::vector<std::int64_t> in_channels_all, int complex_dim)
      : in_channels_all_(std::move(in_channels_all)), complex_dim_(complex_dim) {}
  TORCH_ARG(std::vector<std::int64_t>, in_channels_all);
  TORCH_ARG(int, complex_dim);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool, att) = false;
  TORCH_ARG(bool, topomodelx_compatible) = false;  ///< attention of B_rᵀ queried at rank r-1
};

/// The schedule: per layer, ranks 1 .. complex_dim-1 in turn, the mean of two intra-aggregated
/// Conv messages, then relu.
/// Intra-neighbourhood aggregation (Hajij et al.'s CMPS, TopoModelX SCACMPS's intra_aggr): each
/// row scaled by σ(<relu(Σ_j x_j), x_i>), its agreement with the whole cochain. SCA-CMPS's own
/// operation, through the operator schedule's extension point.
struct IntraAggregate : nn::Operation {
  std::string str(const std::string& x) const override { return "intra(" + x + ")"; }
  nn::TermShape infer(nn::BuildContext&, nn::TermShape x) const override { return x; }
  torch::Tensor forward(nn::RunContext&, const torch::Tensor& x) const override {
    return x * torch::sigmoid(x.matmul(torch::relu(x.sum(0)))).unsqueeze(1);
  }
};

inline nn::OperatorSchedule sca_cmps_schedule(const SCACMPSOptions& o) {
  using namespace nn::ops;
  const auto& ch = o.in_channels_all();
  if (o.complex_dim() < 2 || static_cast<int>(ch.size()) < o.complex_dim())
    throw std::invalid_argument(
        "SCACMPS: complex_dim must be >= 2 and in_channels_all needs complex_dim entries");
  if (o.n_layers() < 1) throw std::invalid_argument("SCACMPS: n_layers must be >= 1");
  nn::OperatorSchedule s;
  for (int r = 0; r < o.complex_dim(); ++r) {
    const auto R = std::to_string(r);
    s.input("x_" + R, r, ch[static_cast<std::size_t>(r)]).output("x_" + R, r);
    if (r > 0)
      s.operator_input("down_laplacian_" + R, r, r)
          .operator_input("incidence_" + R + "_t", r - 1, r);  // rank r-1 -> rank r
  }
  // TopoModelX's Conv: with att, weights elu(a·[x_source_j, x_target_i]) times A's values on the
  // features before the map, applied to x W.
  auto conv = [&](int source, int target, const std::string& path, const std::string& op) {
    auto t = from(source);
    t.conv(path, ch[static_cast<std::size_t>(target)]);
    if (!o.att()) return std::move(t.via(op));
    auto a = nn::AttendOptions(path + ".att_weight").keys(nn::CochainKey{source, ""});
    if (o.topomodelx_compatible()) a.queries(nn::CochainKey{source, ""});
    return std::move(t.attend(op, a));
  };
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".";
    for (int r = 1; r < o.complex_dim(); ++r) {
      const auto R = std::to_string(r), i = std::to_string(r - 1);
      s.step(
          into(r)
              .mean(
                  conv(r, r, p + "lap_layers." + i, "down_laplacian_" + R).apply(IntraAggregate()),
                  conv(r - 1, r, p + "inc_layers." + i, "incidence_" + R + "_t")
                      .apply(IntraAggregate()))
              .act(nn::Activation::relu));
    }
  }
  return s;
}

class SCACMPSImpl : public nn::Cloneable<SCACMPSImpl, nn::OperatorNetworkImpl> {
 public:
  explicit SCACMPSImpl(const SCACMPSOptions& o) : Cloneable(sca_cmps_schedule(o)), options(o) {}
  /// x[r] for r = 0..complex_dim-1; down_laplacians[r-1] = L_r↓ and incidences_t[r-1] = B_rᵀ for r
  /// ≥ 1. Returns every rank's features (rank 0 as given).
  std::vector<torch::Tensor> forward(std::vector<torch::Tensor> x,
                                     const std::vector<nn::SparseOperator>& down_laplacians,
                                     const std::vector<nn::SparseOperator>& incidences_t) {
    const auto D = static_cast<std::size_t>(options.complex_dim());
    if (x.size() < D || down_laplacians.size() < D - 1 || incidences_t.size() < D - 1)
      throw std::invalid_argument("SCACMPS: expected " + std::to_string(D) +
                                  " feature matrices and " + std::to_string(D - 1) +
                                  " lower Laplacians and transposed incidences");
    std::map<std::string, torch::Tensor> in;
    std::map<std::string, nn::SparseOperator> ops;
    std::vector<std::string> out;
    for (std::size_t r = 0; r < D; ++r) {
      const auto R = std::to_string(r);
      in["x_" + R] = x[r];
      out.push_back("x_" + R);
      if (r > 0) {
        ops["down_laplacian_" + R] = down_laplacians[r - 1];
        ops["incidence_" + R + "_t"] = incidences_t[r - 1];
      }
    }
    auto y = run(in, ops, out);
    for (std::size_t r = 0; r < D; ++r) x[r] = y[r];
    return x;
  }
  SCACMPSOptions options;
};
TORCH_MODULE(SCACMPS);

}  // namespace topos::models
