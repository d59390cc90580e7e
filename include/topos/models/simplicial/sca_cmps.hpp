// topos/models/simplicial/sca_cmps.hpp
// SCA with CMPS (Hajij et al., "Simplicial complex representation learning", 2022; TopoModelX
// SCACMPS): ranks 1 .. complex_dim-1 in turn, each from its own features over the lower
// Laplacian and from the rank below (already updated) over B_rᵀ; each message x is reweighted
// per cell by σ(<relu(Σ_cells x), x_i>) (intra-neighbourhood aggregation), the two averaged,
// then relu. Rank 0 passes through. Parameters layers.<i>.lap_layers.<r-1>.weight (and
// att_weight with att) and layers.<i>.inc_layers.<r-1>.*.
#pragma once

#include "topos/nn/conv.hpp"

namespace topos::models {

struct SCACMPSOptions {
  SCACMPSOptions(std::vector<std::int64_t> in_channels_all, int complex_dim)
      : in_channels_all_(std::move(in_channels_all)), complex_dim_(complex_dim) {}
  TORCH_ARG(std::vector<std::int64_t>, in_channels_all);
  TORCH_ARG(int, complex_dim);
  TORCH_ARG(int, n_layers) = 2;
  TORCH_ARG(bool, att) = false;
};

class SCACMPSImpl : public torch::nn::Module {
 public:
  explicit SCACMPSImpl(const SCACMPSOptions& o) : options(o) {
    const auto& ch = o.in_channels_all();
    if (o.complex_dim() < 2 || static_cast<int>(ch.size()) < o.complex_dim())
      throw std::invalid_argument(
          "SCACMPS: complex_dim must be >= 2 and in_channels_all needs complex_dim entries");
    if (o.n_layers() < 1) throw std::invalid_argument("SCACMPS: n_layers must be >= 1");
    auto list = register_module("layers", torch::nn::ModuleList());
    for (int l = 0; l < o.n_layers(); ++l) {
      auto m = std::make_shared<torch::nn::Module>();
      auto lap = m->register_module("lap_layers", torch::nn::ModuleList()),
           inc = m->register_module("inc_layers", torch::nn::ModuleList());
      Layer layer;
      for (int i = 1; i < o.complex_dim(); ++i) {
        const auto c = ch[static_cast<std::size_t>(i)], below = ch[static_cast<std::size_t>(i) - 1];
        layer.lap.push_back(nn::Conv(nn::ConvOptions(c, c).att(o.att())));
        layer.inc.push_back(nn::Conv(nn::ConvOptions(below, c).att(o.att())));
        lap->push_back(layer.lap.back());
        inc->push_back(layer.inc.back());
      }
      layers_.push_back(std::move(layer));
      list->push_back(m);
    }
  }
  /// x[r] for r = 0..complex_dim-1; down_laplacians[r-1] = L_r↓ and incidences_t[r-1] = B_rᵀ for r
  /// ≥ 1.
  std::vector<torch::Tensor> forward(std::vector<torch::Tensor> x,
                                     const std::vector<nn::SparseOperator>& down_laplacians,
                                     const std::vector<nn::SparseOperator>& incidences_t) {
    const auto D = static_cast<std::size_t>(options.complex_dim());
    if (x.size() < D || down_laplacians.size() < D - 1 || incidences_t.size() < D - 1)
      throw std::invalid_argument("SCACMPS: expected " + std::to_string(D) +
                                  " feature matrices and " + std::to_string(D - 1) +
                                  " lower Laplacians and transposed incidences");
    for (auto& l : layers_)
      for (std::size_t i = 1; i < D; ++i) {
        const auto x_lap = intra_aggregate(l.lap[i - 1]->forward(x[i], down_laplacians[i - 1]));
        const auto x_inc = intra_aggregate(l.inc[i - 1]->forward(x[i - 1], incidences_t[i - 1]));
        x[i] = nn::aggregate_messages({x_lap, x_inc}, nn::Aggr::mean, nn::Update::relu);
      }
    return x;
  }
  SCACMPSOptions options;

 private:
  /// Row i scaled by σ(<relu(Σ_j x_j), x_i>).
  static torch::Tensor intra_aggregate(const torch::Tensor& x) {
    const auto w = torch::sigmoid(x.matmul(torch::relu(x.sum(0))));
    return x * w.unsqueeze(1);
  }
  struct Layer {
    std::vector<nn::Conv> lap, inc;
  };
  std::vector<Layer> layers_;
};
TORCH_MODULE(SCACMPS);

}  // namespace topos::models
