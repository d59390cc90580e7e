// topos/models/simplicial/sccnn.hpp
// SCCNN (Yang & Isufi, "Convolutional learning on simplicial complexes", 2023; TopoModelX
// SCCNN): per rank, a polynomial filter of the lower and upper Laplacians applied to the rank's
// own features and to the features projected from the ranks below and above (B xᵣ₊₁, Bᵀ xᵣ₋₁),
// all terms combined by one weight tensor weight_r (in × out × terms). The identity terms and
// the degree normalisation are sparse (TopoModelX builds dense n × n matrices for them).
// Written as an operator schedule (sccnn_schedule).
#pragma once

#include "topos/nn/operator_schedule.hpp"

namespace topos::models {

struct SCCNNOptions {
  SCCNNOptions(std::vector<std::int64_t> in, std::vector<std::int64_t> hidden, int conv_order,
               int sc_order)
      : in_channels_all_(std::move(in)),
        hidden_channels_all_(std::move(hidden)),
        conv_order_(conv_order),
        sc_order_(sc_order) {}
  TORCH_ARG(std::vector<std::int64_t>, in_channels_all);
  TORCH_ARG(std::vector<std::int64_t>, hidden_channels_all);
  TORCH_ARG(int, conv_order);
  TORCH_ARG(int, sc_order);
  TORCH_ARG(bool, aggr_norm) =
      false;  ///< divide each power by the Laplacian's row sums (0 where they are 0)
  TORCH_ARG(nn::Activation, update_func) = nn::Activation::none;
  TORCH_ARG(int, n_layers) = 2;
};

/// The schedule: per rank a linear map, then per layer one parallel group whose step for rank r
/// mixes the filter terms of its own features and of those projected from ranks r ± 1.
inline nn::OperatorSchedule sccnn_schedule(const SCCNNOptions& o) {
  using namespace nn::ops;
  const auto& in = o.in_channels_all();
  const auto& h = o.hidden_channels_all();
  if (in.size() != 3 || h.size() != 3)
    throw std::invalid_argument(
        "SCCNN: in_channels_all and hidden_channels_all need 3 entries (ranks 0, 1, 2)");
  if (h[0] != h[1] || h[1] != h[2])
    throw std::invalid_argument(
        "SCCNN: the hidden channels must be equal on every rank (the incidences mix ranks)");
  if (o.conv_order() < 1 || o.sc_order() < 2)
    throw std::invalid_argument("SCCNN: conv_order must be >= 1 and sc_order >= 2");
  const auto u = o.update_func();
  if (u != nn::Activation::none && u != nn::Activation::relu && u != nn::Activation::sigmoid)
    throw std::invalid_argument("SCCNN: update_func must be relu, sigmoid or none");
  const bool norm = o.aggr_norm();
  const int K = o.conv_order();
  // With sc_order 2 the faces have one Laplacian, passed as both laplacian_down_2 and _up_2.
  const std::string up2 = o.sc_order() > 2 ? "laplacian_up_2" : "laplacian_down_2";
  nn::OperatorSchedule s;
  s.operator_input("laplacian_0", 0, 0)
      .operator_input("laplacian_down_1", 1, 1)
      .operator_input("laplacian_up_1", 1, 1)
      .operator_input("laplacian_down_2", 2, 2)
      .operator_input(up2, 2, 2)
      .operator_input("incidence_1", 1, 0)
      .operator_input("incidence_2", 2, 1);
  std::vector<nn::OperatorStep> encode;
  for (int r = 0; r < 3; ++r) {
    const auto R = std::to_string(r);
    s.input("x_" + R, r, in[static_cast<std::size_t>(r)]).output("x_" + R, r);
    encode.push_back(into(r).sum(from(r).linear("in_linear_" + R, h[0])));
  }
  s.parallel(std::move(encode));
  auto f = [&](const std::string& op) { return std::make_pair(op, K); };
  for (int l = 0; l < o.n_layers(); ++l) {
    const auto p = "layers." + std::to_string(l) + ".weight_";
    std::vector<Term> faces{from(2).powers({f("laplacian_down_2")}, norm)};
    if (o.sc_order() > 2) faces[0] = from(2).powers({f("laplacian_down_2"), f(up2)}, norm);
    faces.push_back(from(1).via_t("incidence_2").powers({f("laplacian_down_2")}, norm));
    s.parallel({into(0)
                    .filter(p + "0", h[0], from(0).powers({f("laplacian_0")}, norm),
                            from(1).via("incidence_1").powers({f("laplacian_0")}, norm))
                    .act(u),
                into(1)
                    .filter(p + "1", h[0],
                            from(0).via_t("incidence_1").powers({f("laplacian_down_1")}, norm),
                            from(1).powers({f("laplacian_down_1"), f("laplacian_up_1")}, norm),
                            from(2).via("incidence_2").powers({f("laplacian_up_1")}, norm))
                    .act(u),
                into(2).filter(p + "2", h[0], std::move(faces)).act(u)});
  }
  return s;
}

class SCCNNImpl : public nn::Cloneable<SCCNNImpl, nn::OperatorNetworkImpl> {
 public:
  explicit SCCNNImpl(const SCCNNOptions& o) : Cloneable(sccnn_schedule(o)), options(o) {
    // TopoModelX's initialisation of the filter weights.
    torch::NoGradGuard g;
    for (int l = 0; l < o.n_layers(); ++l)
      for (int r = 0; r < 3; ++r)
        torch::nn::init::xavier_normal_(
            parameter("layers." + std::to_string(l) + ".weight_" + std::to_string(r)), 1.414);
  }

  /// x = (x_0, x_1, x_2); laplacians = (L_0, L_down_1, L_up_1, L_2) for sc_order 2, else
  /// (L_0, L_down_1, L_up_1, L_down_2, L_up_2); incidences = (B_1, B_2).
  std::vector<torch::Tensor> forward(const std::vector<torch::Tensor>& x,
                                     const std::vector<nn::SparseOperator>& L,
                                     const std::vector<nn::SparseOperator>& B) {
    const bool two = options.sc_order() == 2;
    if (x.size() != 3) throw std::invalid_argument("SCCNN: expected features of ranks 0, 1, 2");
    if (L.size() != (two ? 4u : 5u) || B.size() != 2)
      throw std::invalid_argument(std::string("SCCNN: expected ") + (two ? "4" : "5") +
                                  " Laplacians and 2 incidences");
    std::map<std::string, nn::SparseOperator> ops{
        {"laplacian_0", L[0]},      {"laplacian_down_1", L[1]}, {"laplacian_up_1", L[2]},
        {"laplacian_down_2", L[3]}, {"incidence_1", B[0]},      {"incidence_2", B[1]}};
    if (!two) ops["laplacian_up_2"] = L[4];
    return run({{"x_0", x[0]}, {"x_1", x[1]}, {"x_2", x[2]}}, ops, {"x_0", "x_1", "x_2"});
  }
  SCCNNOptions options;
};
TORCH_MODULE(SCCNN);

}  // namespace topos::models
