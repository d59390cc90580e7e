// topos/models/zoo.hpp
// The model zoo by TopoModelX class name: builds a model from its TopoModelX constructor
// arguments (a JSON object, as in a golden case's "config"; an unknown or mistyped argument is
// an error naming it) and runs it on TopoModelX's positional forward arguments (tensors,
// operators, tuples/lists of them, None). Used by `tdl forward` / `tdl grad` and the parity tests.
#pragma once

#include "topos/models/cell/can.hpp"
#include "topos/models/cell/ccxn.hpp"
#include "topos/models/cell/cwn.hpp"
#include "topos/models/combinatorial/hmc.hpp"
#include "topos/models/hypergraph/allset_transformer.hpp"
#include "topos/models/hypergraph/hmpnn.hpp"
#include "topos/models/hypergraph/hnhn.hpp"
#include "topos/models/hypergraph/hypergat.hpp"
#include "topos/models/hypergraph/hypersage.hpp"
#include "topos/models/hypergraph/unigcn.hpp"
#include "topos/models/hypergraph/unigcnii.hpp"
#include "topos/models/hypergraph/unigin.hpp"
#include "topos/models/hypergraph/unisage.hpp"
#include "topos/models/simplicial/dist2cycle.hpp"
#include "topos/models/simplicial/hsn.hpp"
#include "topos/models/simplicial/san.hpp"
#include "topos/models/simplicial/sca_cmps.hpp"
#include "topos/models/simplicial/sccn.hpp"
#include "topos/models/simplicial/sccnn.hpp"
#include "topos/models/simplicial/scconv.hpp"
#include "topos/models/simplicial/scn2.hpp"
#include "topos/models/simplicial/scnn.hpp"
#include "topos/models/simplicial/scone.hpp"

#include <nlohmann/json.hpp>

#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::models {

class ZooError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// One positional forward argument: a feature tensor, an operator, None, a tuple/list, or a
/// dict (a list whose items carry their keys).
struct ZooArg {
  enum class Kind { none, tensor, op, list, dict } kind = Kind::none;
  std::string name;  ///< for errors
  std::string key;   ///< an item's key in a dict
  torch::Tensor tensor;
  nn::SparseOperator op;
  std::vector<ZooArg> items;

  static ZooArg of(torch::Tensor t, std::string n) {
    ZooArg a;
    a.kind = Kind::tensor;
    a.tensor = std::move(t);
    a.name = std::move(n);
    return a;
  }
  static ZooArg of(nn::SparseOperator o, std::string n) {
    ZooArg a;
    a.kind = Kind::op;
    a.op = std::move(o);
    a.name = std::move(n);
    return a;
  }
  static ZooArg list(std::vector<ZooArg> v) {
    ZooArg a;
    a.kind = Kind::list;
    a.items = std::move(v);
    a.name = "(list)";
    return a;
  }
  static ZooArg dict(std::vector<ZooArg> v) {
    ZooArg a;
    a.kind = Kind::dict;
    a.items = std::move(v);
    a.name = "(dict)";
    return a;
  }
};

/// A model and how to call it with TopoModelX's positional arguments.
struct ZooModel {
  std::string name;
  std::shared_ptr<torch::nn::Module> module;
  std::function<std::vector<torch::Tensor>(const std::vector<ZooArg>&)> forward;
};

namespace detail {

/// Typed access to a constructor-argument object; finish() rejects arguments nobody read.
class Config {
 public:
  Config(const nlohmann::json& j, std::string model) : j_(j), model_(std::move(model)) {
    if (!j_.is_object()) throw ZooError(model_ + ": config must be a JSON object");
  }
  bool has(const std::string& k) const { return j_.contains(k) && !j_.at(k).is_null(); }
  /// Given as null (Python's None), which can differ from absent (the default).
  bool is_null(const std::string& k) const { return j_.contains(k) && j_.at(k).is_null(); }
  template <class T>
  T get(const std::string& k, T fallback) {
    used_.insert(k);
    return has(k) ? as<T>(k) : fallback;
  }
  template <class T>
  T need(const std::string& k) {
    used_.insert(k);
    if (!has(k)) throw ZooError(model_ + ": config lacks '" + k + "'");
    return as<T>(k);
  }
  nn::Update update(const std::string& k, nn::Update fallback) {
    used_.insert(k);
    if (!has(k)) return fallback;
    try {
      return nn::update_from_string(as<std::string>(k));
    } catch (const std::invalid_argument& e) {
      throw ZooError(model_ + ": config '" + k + "': " + e.what());
    }
  }
  void finish() const {
    for (const auto& [k, v] : j_.items())
      if (!used_.count(k)) throw ZooError(model_ + ": unknown config parameter '" + k + "'");
  }

 private:
  template <class T>
  T as(const std::string& k) const {
    try {
      return j_.at(k).get<T>();
    } catch (const nlohmann::json::exception&) {
      throw ZooError(model_ + ": config '" + k + "' has the wrong type (" + j_.at(k).dump() + ")");
    }
  }
  const nlohmann::json& j_;
  std::string model_;
  std::set<std::string> used_;
};

/// Checks the argument count and kinds, then gives typed access.
class Args {
 public:
  Args(const std::vector<ZooArg>& a, const std::string& model, std::size_t min, std::size_t max)
      : a_(a), model_(model) {
    if (a.size() < min || a.size() > max)
      throw ZooError(
          model + ": forward takes " +
          (min == max ? std::to_string(min) : std::to_string(min) + " to " + std::to_string(max)) +
          " arguments, got " + std::to_string(a.size()));
  }
  std::size_t size() const { return a_.size(); }
  torch::Tensor tensor(std::size_t i) const { return tensor_of(at(i), i); }
  const nn::SparseOperator& op(std::size_t i) const { return op_of(at(i), i); }
  std::vector<torch::Tensor> tensors(std::size_t i) const {
    std::vector<torch::Tensor> out;
    for (const auto& x : list(i)) out.push_back(tensor_of(x, i));
    return out;
  }
  std::vector<nn::SparseOperator> ops(std::size_t i) const {
    std::vector<nn::SparseOperator> out;
    for (const auto& x : list(i)) out.push_back(op_of(x, i));
    return out;
  }
  /// Items "<prefix><k>" for k = first..last of a dict argument (SCCN's "rank_<k>").
  std::vector<torch::Tensor> tensors(std::size_t i, const std::string& prefix, int first,
                                     int last) const {
    std::vector<torch::Tensor> out;
    for (int k = first; k <= last; ++k)
      out.push_back(tensor_of(item(i, prefix + std::to_string(k)), i));
    return out;
  }
  std::vector<nn::SparseOperator> ops(std::size_t i, const std::string& prefix, int first,
                                      int last) const {
    std::vector<nn::SparseOperator> out;
    for (int k = first; k <= last; ++k)
      out.push_back(op_of(item(i, prefix + std::to_string(k)), i));
    return out;
  }
  bool is_none(std::size_t i) const { return at(i).kind == ZooArg::Kind::none; }

 private:
  const ZooArg& at(std::size_t i) const { return a_.at(i); }
  const ZooArg& item(std::size_t i, const std::string& key) const {
    if (at(i).kind != ZooArg::Kind::dict)
      throw ZooError(model_ + ": forward argument " + std::to_string(i) + " must be a dict");
    for (const auto& x : at(i).items)
      if (x.key == key) return x;
    throw ZooError(model_ + ": forward argument " + std::to_string(i) + " lacks the key '" + key +
                   "'");
  }
  const std::vector<ZooArg>& list(std::size_t i) const {
    if (at(i).kind != ZooArg::Kind::list)
      throw ZooError(model_ + ": forward argument " + std::to_string(i) +
                     " must be a tuple or list");
    return at(i).items;
  }
  torch::Tensor tensor_of(const ZooArg& x, std::size_t i) const {
    if (x.kind != ZooArg::Kind::tensor)
      throw ZooError(model_ + ": forward argument " + std::to_string(i) + " ('" + x.name +
                     "') must be a feature tensor");
    return x.tensor;
  }
  const nn::SparseOperator& op_of(const ZooArg& x, std::size_t i) const {
    if (x.kind != ZooArg::Kind::op)
      throw ZooError(model_ + ": forward argument " + std::to_string(i) + " ('" + x.name +
                     "') must be an operator");
    return x.op;
  }
  const std::vector<ZooArg>& a_;
  std::string model_;
};

using Maker = std::function<ZooModel(Config&, bool compatible)>;

template <class M>
ZooModel wrap(const std::string& name, M m,
              std::function<std::vector<torch::Tensor>(M&, const Args&)> call, std::size_t min_args,
              std::size_t max_args) {
  ZooModel z;
  z.name = name;
  z.module = m.ptr();
  z.forward = [name, m, call, min_args, max_args](const std::vector<ZooArg>& a) mutable {
    return call(m, Args(a, name, min_args, max_args));
  };
  return z;
}

/// A torch.nn activation class named in a config ("torch.nn.ReLU"); absent or null: `fallback`
/// (std::nullopt: TopoModelX received None).
inline std::optional<nn::Update> torch_activation(Config& c, const std::string& k,
                                                  std::optional<nn::Update> fallback) {
  const auto name = c.get<std::string>(k, "");
  if (name.empty()) return fallback;
  static const std::map<std::string, nn::Update> known = {{"ReLU", nn::Update::relu},
                                                          {"Sigmoid", nn::Update::sigmoid},
                                                          {"Tanh", nn::Update::tanh},
                                                          {"ELU", nn::Update::elu},
                                                          {"LeakyReLU", nn::Update::leaky_relu},
                                                          {"Identity", nn::Update::none}};
  const auto bare = name.rfind("torch.nn.", 0) == 0 ? name.substr(9) : name;
  auto it = known.find(bare);
  if (it == known.end())
    throw ZooError("config '" + k + "': unsupported activation '" + name +
                   "' (torch.nn.ReLU, Sigmoid, Tanh, ELU, LeakyReLU, Identity)");
  return it->second;
}

/// A torch.nn normalisation class named in a config (AllSet's mlp_norm); absent or null: none.
inline MlpNorm torch_norm(Config& c, const std::string& k) {
  const auto name = c.get<std::string>(k, "");
  if (name.empty()) return MlpNorm::none;
  if (name == "torch.nn.LayerNorm" || name == "LayerNorm") return MlpNorm::layer_norm;
  if (name == "torch.nn.BatchNorm1d" || name == "BatchNorm1d") return MlpNorm::batch_norm;
  throw ZooError("config '" + k + "': unsupported normalisation '" + name +
                 "' (torch.nn.LayerNorm, torch.nn.BatchNorm1d)");
}

inline nn::Aggr aggr_of(Config& c, const std::string& k, const std::string& fallback) {
  const auto s = c.get<std::string>(k, fallback);
  if (s == "sum" || s == "add") return nn::Aggr::sum;
  if (s == "mean") return nn::Aggr::mean;
  throw ZooError("config '" + k + "': unknown aggregation '" + s + "' (sum, mean)");
}

/// Weight initialisations TopoModelX offers; they only matter before weights are loaded.
inline std::string initialization_of(Config& c, const std::string& k, const std::string& fallback,
                                     std::initializer_list<const char*> allowed) {
  const auto s = c.get<std::string>(k, fallback);
  for (const char* a : allowed)
    if (s == a) return s;
  throw ZooError("config '" + k + "': unknown initialization '" + s + "'");
}

/// The hypergraph models: forward(x_0, incidence_1) (HMPNN: x_0, x_1, incidence_1).
inline std::map<std::string, Maker> hypergraph_makers() {
  using nn::Update;
  return {
      {"AllSet",
       [](Config& c, bool compatible) {
         AllSet net(AllSetOptions(c.need<std::int64_t>("in_channels"),
                                  c.need<std::int64_t>("hidden_channels"))
                        .n_layers(c.get("n_layers", 2))
                        .layer_dropout(c.get("layer_dropout", 0.2))
                        .mlp_num_layers(c.get("mlp_num_layers", 2))
                        .mlp_activation(torch_activation(c, "mlp_activation", std::nullopt))
                        .mlp_dropout(c.get("mlp_dropout", 0.0))
                        .mlp_norm(torch_norm(c, "mlp_norm"))
                        .topomodelx_compatible(compatible));
         return wrap<AllSet>(
             "AllSet", net,
             [](AllSet& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"AllSetTransformer",
       [](Config& c, bool) {
         AllSetTransformer net(
             AllSetTransformerOptions(c.need<std::int64_t>("in_channels"),
                                      c.need<std::int64_t>("hidden_channels"))
                 .n_layers(c.get("n_layers", 1))
                 .heads(c.get("heads", 4))
                 .number_queries(c.get("number_queries", 1))
                 .dropout(c.get("dropout", 0.2))
                 .mlp_num_layers(c.get("mlp_num_layers", 2))
                 .mlp_activation(torch_activation(c, "mlp_activation", Update::relu))
                 .mlp_dropout(c.get("mlp_dropout", 0.2))
                 .mlp_norm(torch_norm(c, "mlp_norm")));
         return wrap<AllSetTransformer>(
             "AllSetTransformer", net,
             [](AllSetTransformer& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); },
             2, 2);
       }},
      {"HNHN",
       [](Config& c, bool) {
         if (c.has("incidence_1"))
           throw ZooError(
               "HNHN: config 'incidence_1' must be null (pass the incidence to forward)");
         c.get<std::string>("incidence_1", "");  // null: read
         initialization_of(c, "bias_init", "xavier_uniform", {"xavier_uniform", "xavier_normal"});
         HNHN net(HNHNOptions(c.need<std::int64_t>("in_channels"),
                              c.need<std::int64_t>("hidden_channels"))
                      .n_layers(c.get("n_layers", 2))
                      .layer_drop(c.get("layer_drop", 0.2))
                      .use_bias(c.get("use_bias", true))
                      .use_normalized_incidence(c.get("use_normalized_incidence", true))
                      .alpha(c.get("alpha", -1.5))
                      .beta(c.get("beta", -0.5))
                      .bias_gain(c.get("bias_gain", 1.414)));
         return wrap<HNHN>(
             "HNHN", net, [](HNHN& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); },
             2, 2);
       }},
      {"HyperGAT",
       [](Config& c, bool compatible) {
         initialization_of(c, "initialization", "xavier_uniform",
                           {"xavier_uniform", "xavier_normal"});
         HyperGAT net(HyperGATOptions(c.need<std::int64_t>("in_channels"),
                                      c.need<std::int64_t>("hidden_channels"))
                          .n_layers(c.get("n_layers", 2))
                          .layer_drop(c.get("layer_drop", 0.2))
                          .update_func(c.update("update_func", Update::relu))
                          .initialization_gain(c.get("initialization_gain", 1.414))
                          .topomodelx_compatible(compatible));
         return wrap<HyperGAT>(
             "HyperGAT", net,
             [](HyperGAT& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"HyperSAGE",
       [](Config& c, bool compatible) {
         const auto init = initialization_of(c, "initialization", "uniform",
                                             {"uniform", "xavier_uniform", "xavier_normal"});
         if (c.get<std::string>("device", "cpu") != "cpu")
           throw ZooError("HyperSAGE: config 'device' must be \"cpu\"");
         HyperSAGE net(HyperSAGEOptions(c.need<std::int64_t>("in_channels"),
                                        c.need<std::int64_t>("hidden_channels"))
                           .n_layers(c.get("n_layers", 2))
                           .alpha(c.get("alpha", -1))
                           .update_func(c.update("update_func", Update::relu))
                           .uniform_initialization(init == "uniform")
                           .topomodelx_compatible(compatible));
         return wrap<HyperSAGE>(
             "HyperSAGE", net,
             [](HyperSAGE& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"UniGCN",
       [](Config& c, bool compatible) {
         UniGCN net(UniGCNOptions(c.need<std::int64_t>("in_channels"),
                                  c.need<std::int64_t>("hidden_channels"))
                        .n_layers(c.get("n_layers", 2))
                        .aggr_norm(c.get("aggr_norm", false))
                        .use_bn(c.get("use_bn", false))
                        .topomodelx_compatible(compatible));
         return wrap<UniGCN>(
             "UniGCN", net,
             [](UniGCN& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"UniGIN",
       [](Config& c, bool compatible) {
         UniGIN net(UniGINOptions(c.need<std::int64_t>("in_channels"),
                                  c.need<std::int64_t>("hidden_channels"))
                        .n_layers(c.get("n_layers", 2))
                        .input_drop(c.get("input_drop", 0.2))
                        .layer_drop(c.get("layer_drop", 0.2))
                        .eps(c.get("eps", 0.0))
                        .train_eps(c.get("train_eps", false))
                        .use_norm(c.get("use_norm", false))
                        .topomodelx_compatible(compatible));
         return wrap<UniGIN>(
             "UniGIN", net,
             [](UniGIN& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"UniSAGE",
       [](Config& c, bool) {
         UniSAGE net(UniSAGEOptions(c.need<std::int64_t>("in_channels"),
                                    c.need<std::int64_t>("hidden_channels"))
                         .n_layers(c.get("n_layers", 2))
                         .input_drop(c.get("input_drop", 0.2))
                         .layer_drop(c.get("layer_drop", 0.2))
                         .e_aggr(aggr_of(c, "e_aggr", "sum"))
                         .v_aggr(aggr_of(c, "v_aggr", "mean"))
                         .use_norm(c.get("use_norm", false)));
         return wrap<UniSAGE>(
             "UniSAGE", net,
             [](UniSAGE& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
       }},
      {"HMPNN",
       [](Config& c, bool compatible) {
         HMPNN net(HMPNNOptions(c.need<std::int64_t>("in_channels"),
                                c.need<std::int64_t>("hidden_channels"))
                       .n_layers(c.get("n_layers", 2))
                       .adjacency_dropout_rate(c.get("adjacency_dropout_rate", 0.7))
                       .regular_dropout_rate(c.get("regular_dropout_rate", 0.5))
                       .aggr_func(aggr_of(c, "aggr_func", "sum"))
                       .topomodelx_compatible(compatible));
         return wrap<HMPNN>(
             "HMPNN", net,
             [](HMPNN& n, const Args& a) { return n->forward(a.tensor(0), a.tensor(1), a.op(2)); },
             3, 3);
       }},
  };
}

/// SCNN, HSN, SCConv, SCoNe, SCCN, Dist2Cycle, SCA-CMPS (simplicial); CAN, CCXN (cell).
inline std::map<std::string, Maker> more_simplicial_and_cell_makers() {
  using nn::Update;
  return {
      {"SCNN",
       [](Config& c, bool compatible) {
         SCNN net(SCNNOptions(c.need<std::int64_t>("in_channels"),
                              c.need<std::int64_t>("hidden_channels"),
                              c.need<int>("conv_order_down"), c.need<int>("conv_order_up"))
                      .aggr_norm(c.get("aggr_norm", false))
                      .update_func(c.update("update_func", Update::none))
                      .n_layers(c.get("n_layers", 2))
                      .topomodelx_compatible(compatible));
         return wrap<SCNN>(
             "SCNN", net,
             [](SCNN& n, const Args& a) {
               return std::vector<torch::Tensor>{n->forward(a.tensor(0), a.op(1), a.op(2))};
             },
             3, 3);
       }},
      {"HSN",
       [](Config& c, bool) {
         HSN net(HSNOptions(c.need<std::int64_t>("channels")).n_layers(c.get("n_layers", 2)));
         return wrap<HSN>(
             "HSN", net,
             [](HSN& n, const Args& a) {
               return std::vector<torch::Tensor>{n->forward(a.tensor(0), a.op(1), a.op(2))};
             },
             3, 3);
       }},
      {"SCConv",
       [](Config& c, bool) {
         SCConv net(SCConvOptions(c.need<std::int64_t>("node_channels"))
                        .edge_channels(c.get<std::int64_t>("edge_channels", 0))
                        .face_channels(c.get<std::int64_t>("face_channels", 0))
                        .n_layers(c.get("n_layers", 2)));
         return wrap<SCConv>(
             "SCConv", net,
             [](SCConv& n, const Args& a) {
               return n->forward({a.tensor(0), a.tensor(1), a.tensor(2)},
                                 SCConvOperators{a.op(3), a.op(4), a.op(5), a.op(6), a.op(7),
                                                 a.op(8), a.op(9), a.op(10)});
             },
             11, 11);
       }},
      {"SCoNe",
       [](Config& c, bool) {
         SCoNe net(SCoNeOptions(c.need<std::int64_t>("in_channels"),
                                c.need<std::int64_t>("hidden_channels"), c.need<int>("n_layers")));
         return wrap<SCoNe>(
             "SCoNe", net,
             [](SCoNe& n, const Args& a) {
               return std::vector<torch::Tensor>{n->forward(a.tensor(0), a.op(1), a.op(2))};
             },
             3, 3);
       }},
      {"SCCN",
       [](Config& c, bool) {
         const auto update =
             c.is_null("update_func") ? Update::none : c.update("update_func", Update::sigmoid);
         c.get<std::string>("update_func", "");  // read (null)
         SCCN net(SCCNOptions(c.need<std::int64_t>("channels"), c.need<int>("max_rank"))
                      .n_layers(c.get("n_layers", 2))
                      .update_func(update));
         const int R = net->options.max_rank();
         return wrap<SCCN>(
             "SCCN", net,
             [R](SCCN& n, const Args& a) {
               return n->forward(a.tensors(0, "rank_", 0, R), a.ops(1, "rank_", 1, R),
                                 a.ops(2, "rank_", 0, R));
             },
             3, 3);
       }},
      {"Dist2Cycle",
       [](Config& c, bool compatible) {
         Dist2Cycle net(Dist2CycleOptions(c.need<std::int64_t>("channels"))
                            .n_layers(c.get("n_layers", 2))
                            .topomodelx_compatible(compatible));
         return wrap<Dist2Cycle>(
             "Dist2Cycle", net,
             [](Dist2Cycle& n, const Args& a) {
               return std::vector<torch::Tensor>{n->forward(a.tensor(0), a.op(1), a.op(2))};
             },
             3, 3);
       }},
      {"SCACMPS",
       [](Config& c, bool compatible) {
         SCACMPS net(SCACMPSOptions(c.need<std::vector<std::int64_t>>("in_channels_all"),
                                    c.need<int>("complex_dim"))
                         .n_layers(c.get("n_layers", 2))
                         .att(c.get("att", false))
                         .topomodelx_compatible(compatible));
         return wrap<SCACMPS>(
             "SCACMPS", net,
             [](SCACMPS& n, const Args& a) { return n->forward(a.tensors(0), a.ops(1), a.ops(2)); },
             3, 3);
       }},
      {"CAN",
       [](Config& c, bool compatible) {
         const auto act =
             torch_activation(c, "att_activation",
                              std::nullopt);  // None: LeakyReLU(0.2); a named class: its defaults
         CAN net(CANOptions(c.need<std::int64_t>("in_channels_0"),
                            c.need<std::int64_t>("in_channels_1"),
                            c.need<std::int64_t>("out_channels"))
                     .dropout(c.get("dropout", 0.5))
                     .heads(c.get<std::int64_t>("heads", 2))
                     .concat(c.get("concat", true))
                     .skip_connection(c.get("skip_connection", true))
                     .att_activation(act.value_or(Update::leaky_relu))
                     .att_negative_slope(act ? 0.01 : 0.2)
                     .n_layers(c.get("n_layers", 2))
                     .att_lift(c.get("att_lift", true))
                     .version(c.get<std::string>("version", "v1"))
                     .share_weights(c.get("share_weights", false))
                     .add_self_loops(c.get("add_self_loops", true))
                     .pooling(c.get("pooling", false))
                     .k_pool(c.get("k_pool", 0.5))
                     .topomodelx_compatible(compatible));
         return wrap<CAN>(
             "CAN", net,
             [](CAN& n, const Args& a) {
               return std::vector<torch::Tensor>{
                   n->forward(a.tensor(0), a.tensor(1), a.op(2), a.op(3), a.op(4))};
             },
             5, 5);
       }},
      {"CCXN",
       [](Config& c, bool compatible) {
         CCXN net(CCXNOptions(c.need<std::int64_t>("in_channels_0"),
                              c.need<std::int64_t>("in_channels_1"),
                              c.need<std::int64_t>("in_channels_2"))
                      .n_layers(c.get("n_layers", 2))
                      .att(c.get("att", false))
                      .topomodelx_compatible(compatible));
         return wrap<CCXN>(
             "CCXN", net,
             [](CCXN& n, const Args& a) {
               return n->forward(a.tensor(0), a.tensor(1), a.op(2), a.op(3));
             },
             4, 4);
       }},
  };
}

inline const std::map<std::string, Maker>& makers() {
  static const std::map<std::string, Maker> m = [] {
    std::map<std::string, Maker> m = {
        {"SCN2",
         [](Config& c, bool) {
           SCN2 net(SCN2Options(c.need<std::int64_t>("in_channels_0"),
                                c.need<std::int64_t>("in_channels_1"),
                                c.need<std::int64_t>("in_channels_2"))
                        .n_layers(c.get("n_layers", 2)));
           return wrap<SCN2>(
               "SCN2", net,
               [](SCN2& n, const Args& a) {
                 return n->forward({a.tensor(0), a.tensor(1), a.tensor(2)},
                                   {a.op(3), a.op(4), a.op(5)});
               },
               6, 6);
         }},
        {"SCCNN",
         [](Config& c, bool) {
           SCCNN net(SCCNNOptions(c.need<std::vector<std::int64_t>>("in_channels_all"),
                                  c.need<std::vector<std::int64_t>>("hidden_channels_all"),
                                  c.need<int>("conv_order"), c.need<int>("sc_order"))
                         .aggr_norm(c.get("aggr_norm", false))
                         .update_func(c.update("update_func", nn::Update::none))
                         .n_layers(c.get("n_layers", 2)));
           return wrap<SCCNN>(
               "SCCNN", net,
               [](SCCNN& n, const Args& a) { return n->forward(a.tensors(0), a.ops(1), a.ops(2)); },
               3, 3);
         }},
        {"SAN",
         [](Config& c, bool) {
           SAN net(SANOptions(c.need<std::int64_t>("in_channels"),
                              c.need<std::int64_t>("hidden_channels"))
                       .out_channels(c.get<std::int64_t>("out_channels", 0))
                       .n_filters(c.get("n_filters", 2))
                       .order_harmonic(c.get("order_harmonic", 5))
                       .epsilon_harmonic(c.get("epsilon_harmonic", 0.1))
                       .n_layers(c.get("n_layers", 2)));
           return wrap<SAN>(
               "SAN", net,
               [](SAN& n, const Args& a) {
                 return std::vector<torch::Tensor>{n->forward(a.tensor(0), a.op(1), a.op(2))};
               },
               3, 3);
         }},
        {"CWN",
         [](Config& c, bool) {
           CWN net(CWNOptions(c.need<std::int64_t>("in_channels_0"),
                              c.need<std::int64_t>("in_channels_1"),
                              c.need<std::int64_t>("in_channels_2"),
                              c.need<std::int64_t>("hid_channels"), c.need<int>("n_layers")));
           return wrap<CWN>(
               "CWN", net,
               [](CWN& n, const Args& a) {
                 return n->forward({a.tensor(0), a.tensor(1), a.tensor(2)}, a.op(3), a.op(4),
                                   a.op(5));
               },
               6, 6);
         }},
        {"UniGCNII",
         [](Config& c, bool compatible) {
           UniGCNII net(UniGCNIIOptions(c.need<std::int64_t>("in_channels"),
                                        c.need<std::int64_t>("hidden_channels"))
                            .n_layers(c.get("n_layers", 2))
                            .alpha(c.get("alpha", 0.5))
                            .beta(c.get("beta", 0.5))
                            .input_drop(c.get("input_drop", 0.2))
                            .layer_drop(c.get("layer_drop", 0.2))
                            .use_norm(c.get("use_norm", false))
                            .topomodelx_compatible(compatible));
           return wrap<UniGCNII>(
               "UniGCNII", net,
               [](UniGCNII& n, const Args& a) { return n->forward(a.tensor(0), a.op(1)); }, 2, 2);
         }},
        {"HMC",
         [](Config& c, bool compatible) {
           HMC net(
               HMCOptions(c.need<HMCChannels>("channels_per_layer"))
                   .negative_slope(c.get("negative_slope", 0.2))
                   .update_func_attention(c.update("update_func_attention", nn::Update::relu))
                   .update_func_aggregation(c.update("update_func_aggregation", nn::Update::relu))
                   .topomodelx_compatible(compatible));
           return wrap<HMC>(
               "HMC", net,
               [](HMC& n, const Args& a) {
                 return n->forward({a.tensor(0), a.tensor(1), a.tensor(2)}, a.op(3), a.op(4),
                                   a.op(5), a.op(6), a.op(7));
               },
               8, 8);
         }},
    };
    m.merge(hypergraph_makers());
    m.merge(more_simplicial_and_cell_makers());
    return m;
  }();
  return m;
}

}  // namespace detail

/// TopoModelX class names the zoo builds.
inline std::vector<std::string> zoo_model_names() {
  std::vector<std::string> out;
  for (const auto& [k, v] : detail::makers()) out.push_back(k);
  return out;
}

/// Builds `model` (a TopoModelX class name) from its constructor arguments. With
/// `topomodelx_compatible`, the model reproduces TopoModelX's numbers where they differ from the
/// paper's definition (docs/models.md lists where).
inline ZooModel make_zoo_model(const std::string& model, const nlohmann::json& config,
                               bool topomodelx_compatible = true) {
  const auto& m = detail::makers();
  auto it = m.find(model);
  if (it == m.end()) {
    std::string known;
    for (const auto& [k, v] : m) known += (known.empty() ? "" : ", ") + k;
    throw ZooError("unknown model '" + model + "' (known: " + known + ")");
  }
  detail::Config c(config, model);
  ZooModel z;
  try {
    z = it->second(c, topomodelx_compatible);
  } catch (const ZooError&) {
    throw;
  } catch (const std::exception& e) {
    throw ZooError(model + ": " + e.what());
  }
  c.finish();
  return z;
}

}  // namespace topos::models
