// topos/models/hopnet/batch.hpp
// Frames made ready for the network: the float32 Normalizer, the check that statistics fit a
// model, and make_batch(), which collates frames into a HopnetBatch.
#pragma once

#include "topos/models/hopnet/frame.hpp"
#include "topos/models/hopnet/geometry.hpp"
#include "topos/models/hopnet/neighborhoods.hpp"
#include "topos/models/hopnet/normalization.hpp"
#include "topos/models/hopnet/options.hpp"
#include "topos/models/namespace_aliases.hpp"
#include "topos/nn/complex_batch.hpp"

#include <torch/torch.h>

#include <map>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace topos::models::hopnet {

/// Statistics as float32 tensors, applied as the reference does: (x − mean) / std in float32.
class Normalizer {
 public:
  Normalizer() = default;
  explicit Normalizer(const NormalizationStats& s) : stats_(s) {
    s.validate("normalisation statistics");
    for (const auto& [k, n] : s.keys()) {
      mean_[k] = torch::tensor(s.mean.at(k), torch::kDouble).to(torch::kFloat);
      std_[k] = torch::tensor(s.std.at(k), torch::kDouble).to(torch::kFloat);
    }
    z0_ = -mean_["t0"] / std_["t0"];
    if (s.has_objects()) z4_ = -mean_["t4"] / std_["t4"];
  }
  /// Raw double features (cast to float32 first, as the reference stores them) -> normalised.
  /// One pass on the host with the same float32 operations as the tensor overload (a rollout
  /// normalises six small matrices a step, where four LibTorch operations each cost more).
  torch::Tensor normalize(const std::string& key, const RowMatrix& x) const {
    const auto& [mean, sd] = statistics(key, 2, x.cols());
    auto y = torch::empty({x.rows(), x.cols()}, torch::kFloat);
    const float *m = mean.data_ptr<float>(), *s = sd.data_ptr<float>();
    float* out = y.data_ptr<float>();
    for (Eigen::Index i = 0; i < x.rows(); ++i)
      for (Eigen::Index j = 0; j < x.cols(); ++j)
        out[i * x.cols() + j] = (static_cast<float>(x(i, j)) - m[j]) / s[j];
    return y;
  }
  torch::Tensor normalize(const std::string& key, const torch::Tensor& x) const {
    const auto& [mean, sd] = statistics(key, x.dim(), x.dim() == 2 ? x.size(1) : -1);
    return (x.to(torch::kFloat) - mean.to(x.device())) / sd.to(x.device());
  }
  torch::Tensor denormalize(const std::string& key, const torch::Tensor& y) const {
    return y * std_.at(key).to(y.device()) + mean_.at(key).to(y.device());
  }
  const torch::Tensor& zero_node_acceleration() const { return z0_; }
  /// Undefined for statistics without object entries (no object cells).
  const torch::Tensor& zero_object_acceleration() const { return z4_; }
  const NormalizationStats& stats() const { return stats_; }

  static torch::Tensor to_tensor(const RowMatrix& x) {
    if (x.size() == 0) return torch::zeros({x.rows(), x.cols()}, torch::kFloat);
    return torch::from_blob(const_cast<double*>(x.data()), {x.rows(), x.cols()}, torch::kDouble)
        .to(torch::kFloat);
  }

 private:
  // The mean and standard deviation of `key` (x3_plus reads x3's), checked against features of
  // `dim` dimensions and `cols` columns.
  std::pair<const torch::Tensor&, const torch::Tensor&> statistics(const std::string& key,
                                                                   std::int64_t dim,
                                                                   std::int64_t cols) const {
    const std::string k = key == "x3_plus" ? "x3" : key;
    auto it = mean_.find(k);
    if (it == mean_.end())
      throw std::invalid_argument("the normalisation statistics have no '" + k +
                                  "' entries (statistics of a model without object cells?)");
    if (dim != 2 || cols != it->second.size(0))
      throw std::invalid_argument(
          "the normalisation statistics give '" + k + "' " + std::to_string(it->second.size(0)) +
          " columns, the features have " + std::to_string(dim == 2 ? cols : -1) +
          ": use the statistics this model variant was trained with");
    return {it->second, std_.at(k)};
  }

  NormalizationStats stats_;
  std::map<std::string, torch::Tensor> mean_, std_;
  torch::Tensor z0_, z4_;
};

/// Throws a clear error when `stats` cannot feed a model configured by `opt` (x0's width, the
/// object entries).
inline void check_stats_fit(const HopnetOptions& opt, const NormalizationStats& stats,
                            const std::string& source) {
  const auto want = static_cast<std::size_t>(opt.lifting().x0_width());
  if (stats.x0_width() != want)
    throw std::invalid_argument(source + ": x0 statistics have " +
                                std::to_string(stats.x0_width()) + " columns, the " +
                                to_string(opt.architecture()) +
                                (opt.center_mass_distance() ? "" : " (no centre-mass distance)") +
                                " model reads " + std::to_string(want) +
                                (opt.architecture() == Architecture::no_object_cells
                                     ? " (no object cells: e.g. normalization/movia-nox4.json)"
                                     : ""));
  if (opt.architecture() != Architecture::no_object_cells && !stats.has_objects())
    throw std::invalid_argument(
        source + ": the statistics have no object (x4, t4) entries, which this model needs");
}

/// Frames ready for the network: normalised inputs and their batched complex.
struct HopnetBatch {
  std::map<std::string, torch::Tensor> inputs;
  nn::ComplexBatch complex;
  HopnetBatch to(const torch::Device& d) const {
    HopnetBatch b{{}, complex.to(d)};
    for (const auto& [k, v] : inputs) b.inputs[k] = v.to(d);
    return b;
  }
};

inline nn::ComplexView hopnet_view(const HopnetGeometry& g, const HopnetFrame& f) {
  return {{g.num_rank0(), g.num_rank1(), f.num_faces(), f.num_contacts(), g.num_objects()},
          hopnet_neighborhoods(g, f)};
}

/// Collates frames (of one scene or several) into one batch.
inline HopnetBatch make_batch(
    const std::vector<std::pair<const HopnetGeometry*, const HopnetFrame*>>& frames,
    const Normalizer& norm) {
  std::vector<nn::ComplexView> views;
  std::map<std::string, std::vector<torch::Tensor>> parts;
  for (const auto& [g, f] : frames) {
    views.push_back(hopnet_view(*g, *f));
    parts["x0"].push_back(norm.normalize("x0", f->x0));
    parts["x1"].push_back(norm.normalize("x1", f->x1));
    parts["x2"].push_back(norm.normalize("x2", f->x2));
    parts["x3"].push_back(norm.normalize("x3", f->x3));
    parts["x3_plus"].push_back(norm.normalize("x3", f->x3_plus));
    if (g->lifting.object_cells()) parts["x4"].push_back(norm.normalize("x4", f->x4));
  }
  HopnetBatch b;
  for (auto& [k, v] : parts) b.inputs[k] = v.size() == 1 ? v[0] : torch::cat(v, 0);
  b.complex = nn::ComplexBatch::collate(views, 4);
  return b;
}

}  // namespace topos::models::hopnet
