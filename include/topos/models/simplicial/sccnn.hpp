// topos/models/simplicial/sccnn.hpp
// SCCNN (Yang & Isufi, "Convolutional learning on simplicial complexes", 2023; TopoModelX
// SCCNN): per rank, a polynomial filter of the lower and upper Laplacians applied to the rank's
// own features and to the features projected from the ranks below and above (B xᵣ₊₁, Bᵀ xᵣ₋₁),
// all terms combined by one weight tensor weight_r (in × out × terms). The identity terms and
// the degree normalisation are sparse (TopoModelX builds dense n × n matrices for them).
#pragma once

#include "topos/nn/conv.hpp"

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
  TORCH_ARG(nn::Update, update_func) = nn::Update::none;
  TORCH_ARG(int, n_layers) = 2;
};

class SCCNNImpl : public torch::nn::Module {
 public:
  explicit SCCNNImpl(const SCCNNOptions& o) : options(o) {
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
    if (o.update_func() != nn::Update::none && o.update_func() != nn::Update::relu &&
        o.update_func() != nn::Update::sigmoid)
      throw std::invalid_argument("SCCNN: update_func must be relu, sigmoid or none");
    const std::int64_t K = o.conv_order();
    for (int r = 0; r < 3; ++r)
      lin_.push_back(register_module(
          "in_linear_" + std::to_string(r),
          torch::nn::Linear(in[static_cast<std::size_t>(r)], h[static_cast<std::size_t>(r)])));
    auto list = register_module("layers", torch::nn::ModuleList());
    const std::array<std::int64_t, 3> terms{2 + 2 * K, 3 + 4 * K,
                                            o.sc_order() > 2 ? 2 + 3 * K : 2 + 2 * K};
    for (int l = 0; l < o.n_layers(); ++l) {
      auto layer = std::make_shared<torch::nn::Module>();
      std::array<torch::Tensor, 3> w;
      for (std::size_t r = 0; r < 3; ++r) {
        w[r] = layer->register_parameter("weight_" + std::to_string(r),
                                         torch::empty({h[r], h[r], terms[r]}));
        torch::NoGradGuard g;
        torch::nn::init::xavier_normal_(w[r], 1.414);
      }
      list->push_back(layer);
      weights_.push_back(w);
    }
  }

  /// x = (x_0, x_1, x_2); laplacians = (L_0, L_down_1, L_up_1, L_2) for sc_order 2, else
  /// (L_0, L_down_1, L_up_1, L_down_2, L_up_2); incidences = (B_1, B_2).
  std::vector<torch::Tensor> forward(const std::vector<torch::Tensor>& x_in,
                                     const std::vector<nn::SparseOperator>& L,
                                     const std::vector<nn::SparseOperator>& B) {
    const bool two = options.sc_order() == 2;
    if (L.size() != (two ? 4u : 5u) || B.size() != 2)
      throw std::invalid_argument(std::string("SCCNN: expected ") + (two ? "4" : "5") +
                                  " Laplacians and 2 incidences");
    std::vector<torch::Tensor> x(3);
    for (std::size_t r = 0; r < 3; ++r) x[r] = lin_[r]->forward(x_in[r]);
    const int K = options.conv_order();
    const bool norm = options.aggr_norm();
    // [y, A y, ..., A^K y] for each operator in turn (the identity term once, first).
    auto filt = [&](const torch::Tensor& y, std::initializer_list<const nn::SparseOperator*> ops) {
      std::vector<torch::Tensor> t{y};
      for (const auto* A : ops)
        for (auto& p : nn::powers(*A, y, K, norm)) t.push_back(p);
      return t;
    };
    auto cat = [](std::vector<torch::Tensor> a, const std::vector<torch::Tensor>& b) {
      a.insert(a.end(), b.begin(), b.end());
      return a;
    };
    const auto &L0 = L[0], &Ld1 = L[1], &Lu1 = L[2];
    const auto &Ld2 = two ? L[3] : L[3], &Lu2 = two ? L[3] : L[4];
    const auto B1t = B[0].t(), B2t = B[1].t();
    for (auto& w : weights_) {
      auto t0 = cat(filt(x[0], {&L0}), filt(nn::spmm(B[0], x[1]), {&L0}));
      auto t1 = cat(cat(filt(nn::spmm(B1t, x[0]), {&Ld1}), filt(x[1], {&Ld1, &Lu1})),
                    filt(nn::spmm(B[1], x[2]), {&Lu1}));
      auto t2 = two ? cat(filt(x[2], {&Ld2}), filt(nn::spmm(B2t, x[1]), {&Ld2}))
                    : cat(filt(x[2], {&Ld2, &Lu2}), filt(nn::spmm(B2t, x[1]), {&Ld2}));
      x = {nn::combine_terms(t0, w[0]), nn::combine_terms(t1, w[1]), nn::combine_terms(t2, w[2])};
      for (auto& y : x) y = nn::apply_update(y, options.update_func());
    }
    return x;
  }
  SCCNNOptions options;

 private:
  std::vector<torch::nn::Linear> lin_;
  std::vector<std::array<torch::Tensor, 3>> weights_;
};
TORCH_MODULE(SCCNN);

}  // namespace topos::models
