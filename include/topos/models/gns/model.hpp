// topos/models/gns/model.hpp
// A graph-network simulator as a LibTorch module: the network of a GraphNetworkSpec, the
// per-column normalisation statistics of its inputs and targets, the collation of timesteps
// (GraphFrame) into one batch of normalised tensors and sparse gather operators, and the loss
// on the dynamic mesh nodes' normalised accelerations (the FIGNet reimplementation's cal_loss).
#pragma once

#include "topos/io/atomic_file.hpp"
#include "topos/models/gns/network.hpp"
#include "topos/models/namespace_aliases.hpp"
#include "topos/nn/cloneable.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>

namespace topos::models::gns {

/// Per-column mean and std by statistics key (GraphNetworkSpec's `statistics` of each set, and
/// "acceleration" for the targets).
struct Statistics {
  std::map<std::string, std::vector<double>> mean, std;

  /// Every key the spec names, with its width; throws std::invalid_argument naming the key.
  void check_fits(const GraphNetworkSpec& spec, const std::string& source) const {
    auto need = [&](const std::string& key, std::int64_t width) {
      for (const auto* m : {&mean, &std}) {
        auto it = m->find(key);
        if (it == m->end())
          throw std::invalid_argument(source + ": no statistics '" + key + "' (" +
                                      (m == &mean ? "mean" : "std") + ")");
        if (static_cast<std::int64_t>(it->second.size()) != width)
          throw std::invalid_argument(source + ": statistics '" + key + "' have " +
                                      std::to_string(it->second.size()) + " columns, expected " +
                                      std::to_string(width));
        for (double v : it->second)
          if (!std::isfinite(v) || (m == &std && !(v > 0)))
            throw std::invalid_argument(source + ": statistics '" + key +
                                        "' hold a non-finite or non-positive value");
      }
    };
    for (const auto& n : spec.nodes) need(n.statistics, n.features);
    for (const auto& e : spec.edges) need(e.statistics, e.features);
    need("acceleration", 3);
  }

  nlohmann::json to_json() const {
    nlohmann::json j = nlohmann::json::object();
    for (const auto& [k, v] : mean) j[k] = {{"mean", v}, {"std", std.at(k)}};
    return j;
  }
  static Statistics from_json(const nlohmann::json& j, const std::string& source) {
    if (!j.is_object()) throw std::invalid_argument(source + ": statistics must be a JSON object");
    Statistics s;
    for (const auto& [k, v] : j.items()) {
      if (!v.is_object() || !v.contains("mean") || !v.contains("std"))
        throw std::invalid_argument(source + ": statistics '" + k + "' need 'mean' and 'std'");
      try {
        s.mean[k] = v.at("mean").get<std::vector<double>>();
        s.std[k] = v.at("std").get<std::vector<double>>();
      } catch (const nlohmann::json::exception&) {
        throw std::invalid_argument(source + ": statistics '" + k + "' are not lists of numbers");
      }
      if (s.mean[k].size() != s.std[k].size())
        throw std::invalid_argument(source + ": statistics '" + k +
                                    "' mean and std differ in length");
    }
    return s;
  }
  void save(const std::string& path) const {
    io::write_file_atomic(path, to_json().dump(1) + "\n");
  }
  static Statistics load(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw std::invalid_argument(path + ": cannot open statistics file");
    nlohmann::json j;
    try {
      in >> j;
    } catch (const nlohmann::json::exception& e) {
      throw std::invalid_argument(path + ": not JSON (" + e.what() + ")");
    }
    return from_json(j, path);
  }
};

/// Population moments per column over every row of every frame added; a std below 1e-10 (a
/// constant column, e.g. the friction of a dataset with one material) becomes 1, so that float
/// rounding of a constant is not magnified (the reimplementation floors it at 1e-8 instead).
class StatisticsAccumulator {
 public:
  explicit StatisticsAccumulator(GraphNetworkSpec spec) : spec_(std::move(spec)) {}
  void add(const GraphFrame& f) {
    for (const auto& n : spec_.nodes) add(n.statistics, f.node_set(n.name).features);
    for (const auto& e : spec_.edges) add(e.statistics, f.edge_set(e.name).features);
    if (f.target.rows() > 0) {
      // Dynamic nodes only, as the reimplementation's warm-up fills its output normaliser.
      RowMatrix t(f.target.rows(), 3);
      Eigen::Index n = 0;
      for (Eigen::Index i = 0; i < f.target.rows(); ++i)
        if (f.dynamic[static_cast<std::size_t>(i)]) t.row(n++) = f.target.row(i);
      add("acceleration", t.topRows(n));
    }
  }
  Statistics finish() const {
    Statistics s;
    for (const auto& [k, m] : moments_) {
      auto& mean = s.mean[k];
      auto& sd = s.std[k];
      for (std::size_t c = 0; c < m.sum.size(); ++c) {
        const double n = std::max(m.count, 1.0), mu = m.sum[c] / n;
        const double var = std::max(m.sum2[c] / n - mu * mu, 0.0);
        mean.push_back(mu);
        sd.push_back(std::sqrt(var) < 1e-10 ? 1.0 : std::sqrt(var));
      }
    }
    return s;
  }

 private:
  struct Moments {
    std::vector<double> sum, sum2;
    double count = 0;
  };
  void add(const std::string& key, const RowMatrix& x) {
    auto& m = moments_[key];
    if (m.sum.empty()) m.sum.assign(static_cast<std::size_t>(x.cols()), 0.0), m.sum2 = m.sum;
    if (static_cast<std::size_t>(x.cols()) != m.sum.size())
      throw std::invalid_argument("statistics '" + key + "': rows of different widths");
    for (Eigen::Index i = 0; i < x.rows(); ++i)
      for (Eigen::Index c = 0; c < x.cols(); ++c)
        m.sum[static_cast<std::size_t>(c)] += x(i, c),
            m.sum2[static_cast<std::size_t>(c)] += x(i, c) * x(i, c);
    m.count += static_cast<double>(x.rows());
  }
  GraphNetworkSpec spec_;
  std::map<std::string, Moments> moments_;
};

/// Several timesteps as one graph: every set's rows stacked frame after frame, indices offset.
struct GraphBatch {
  std::map<std::string, torch::Tensor> inputs;  ///< normalised float32 features by set name
  std::map<std::string, nn::SparseOperator> operators;
  torch::Tensor target;   ///< normalised mesh-node accelerations (nodes × 3), or undefined
  torch::Tensor dynamic;  ///< bool per mesh node
  std::vector<std::int64_t> node_offset;  ///< per frame: its first mesh node (frames + 1)
};

namespace detail {
inline torch::Tensor normalized(const RowMatrix& x, const std::vector<double>& mean,
                                const std::vector<double>& sd) {
  auto t = torch::empty({x.rows(), x.cols()}, torch::kFloat);
  auto* p = t.data_ptr<float>();
  for (Eigen::Index i = 0; i < x.rows(); ++i)
    for (Eigen::Index c = 0; c < x.cols(); ++c)
      *p++ = static_cast<float>((x(i, c) - mean[static_cast<std::size_t>(c)]) /
                                sd[static_cast<std::size_t>(c)]);
  return t;
}
template <class Get>
RowMatrix stacked(const std::vector<const GraphFrame*>& frames, std::int64_t width, Get get) {
  Eigen::Index rows = 0;
  for (const auto* f : frames) rows += get(*f).rows();
  RowMatrix out(rows, width);
  Eigen::Index at = 0;
  for (const auto* f : frames) {
    const RowMatrix& x = get(*f);
    if (x.rows() > 0 && x.cols() != width)
      throw std::invalid_argument("graph batch: a set has " + std::to_string(x.cols()) +
                                  " columns, the model expects " + std::to_string(width));
    out.middleRows(at, x.rows()) = x;
    at += x.rows();
  }
  return out;
}
}  // namespace detail

/// The frames as one batch for `spec`, normalised with `stats` (check_fits first).
inline GraphBatch collate(const GraphNetworkSpec& spec,
                          const std::vector<const GraphFrame*>& frames, const Statistics& stats) {
  GraphBatch b;
  std::map<std::string, std::vector<std::int64_t>> offset;  // per node set: per frame
  for (const auto& n : spec.nodes) {
    auto& o = offset[n.name];
    o.push_back(0);
    for (const auto* f : frames) o.push_back(o.back() + f->node_set(n.name).size());
    const RowMatrix x = detail::stacked(
        frames, n.features,
        [&](const GraphFrame& f) -> const RowMatrix& { return f.node_set(n.name).features; });
    b.inputs[n.name] =
        detail::normalized(x, stats.mean.at(n.statistics), stats.std.at(n.statistics));
  }
  for (const auto& e : spec.edges) {
    const RowMatrix x = detail::stacked(
        frames, e.features,
        [&](const GraphFrame& f) -> const RowMatrix& { return f.edge_set(e.name).features; });
    b.inputs[e.name] =
        detail::normalized(x, stats.mean.at(e.statistics), stats.std.at(e.statistics));
    for (int side = 0; side < 2; ++side) {
      const auto& ends = offset.at(side == 0 ? e.sender : e.receiver);
      for (int k = 0; k < e.slots; ++k) {
        std::vector<std::int64_t> rows, cols;
        rows.reserve(static_cast<std::size_t>(x.rows()));
        cols.reserve(rows.capacity());
        std::int64_t row = 0;
        for (std::size_t fi = 0; fi < frames.size(); ++fi) {
          const auto& es = frames[fi]->edge_set(e.name);
          const IndexMatrix& idx = side == 0 ? es.senders : es.receivers;
          if (idx.rows() != es.size() || idx.cols() != e.slots)
            throw std::invalid_argument(
                "graph batch: edge set '" + e.name + "' has " + std::to_string(idx.rows()) + " x " +
                std::to_string(idx.cols()) + " " + (side == 0 ? "senders" : "receivers") +
                ", expected " + std::to_string(es.size()) + " x " + std::to_string(e.slots));
          const std::int64_t n = ends[fi + 1] - ends[fi];
          for (Eigen::Index i = 0; i < idx.rows(); ++i, ++row) {
            const std::int64_t v = idx(i, k);
            if (v < 0 || v >= n)
              throw std::invalid_argument("graph batch: edge set '" + e.name + "' names node " +
                                          std::to_string(v) + " of a set of " + std::to_string(n));
            rows.push_back(row);
            cols.push_back(ends[fi] + v);
          }
        }
        b.operators[gather_operator(e, side == 0, k)] = nn::SparseOperator::from_sorted(
            x.rows(), ends.back(), rows, cols, torch::ones({x.rows()}, torch::kFloat));
      }
    }
  }
  b.node_offset = offset.at(spec.nodes.front().name);
  bool targets = !frames.empty();
  for (const auto* f : frames) targets = targets && f->target.rows() > 0;
  if (targets) {
    const RowMatrix t = detail::stacked(
        frames, 3, [](const GraphFrame& f) -> const RowMatrix& { return f.target; });
    b.target = detail::normalized(t, stats.mean.at("acceleration"), stats.std.at("acceleration"));
  }
  std::vector<char> dyn;
  for (const auto* f : frames) dyn.insert(dyn.end(), f->dynamic.begin(), f->dynamic.end());
  b.dynamic = torch::tensor(std::vector<std::int64_t>(dyn.begin(), dyn.end())).to(torch::kBool);
  return b;
}

/// The network of a spec, registered as one submodule (`root`, the reimplementation's
/// `_encode_process_decode`), so that parameter names are <root>.<schedule path>.
struct GraphNetworkOptions {
  GraphNetworkSpec spec;
  std::string root;  ///< the submodule's name, the first part of every parameter name
};

class GraphNetworkImpl : public nn::Cloneable<GraphNetworkImpl> {
 public:
  explicit GraphNetworkImpl(GraphNetworkOptions o)
      : options(std::move(o)),
        network(register_module(options.root,
                                nn::OperatorNetwork(graph_network_schedule(options.spec)))) {}
  GraphNetworkImpl(GraphNetworkSpec spec, const std::string& root)
      : GraphNetworkImpl(GraphNetworkOptions{std::move(spec), root}) {}
  /// The decoded node sets by name (normalised outputs).
  std::map<std::string, torch::Tensor> forward(const GraphBatch& b) {
    return network->forward(b.inputs, b.operators);
  }
  const GraphNetworkSpec& spec() const { return options.spec; }

  GraphNetworkOptions options;
  nn::OperatorNetwork network;
};
TORCH_MODULE(GraphNetwork);

/// Σ over dynamic mesh nodes of the squared error of the normalised accelerations, divided by
/// the number of dynamic nodes (the reimplementation's cal_loss).
inline torch::Tensor acceleration_loss(const torch::Tensor& predicted, const GraphBatch& b) {
  if (!b.target.defined())
    throw std::invalid_argument("acceleration_loss: the batch has no targets");
  const auto mask = b.dynamic.to(predicted.device());
  const auto n = mask.sum().clamp_min(1);
  return ((predicted - b.target.to(predicted.device())).pow(2).sum(1) * mask).sum() / n;
}

}  // namespace topos::models::gns
