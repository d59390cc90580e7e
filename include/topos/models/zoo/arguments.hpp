// topos/models/zoo/arguments.hpp
// TopoModelX's positional forward arguments (ZooArg) and their checked access (Args), the built
// ZooModel, and wrap(), which binds a module to its forward call for a Maker.
#pragma once

#include "topos/models/zoo/config.hpp"
#include "topos/nn/sparse_operator.hpp"

#include <torch/torch.h>

#include <cstddef>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace topos::models::zoo {

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
  /// A deep copy (the module's clone(): same options, parameters and mode) with its forward.
  std::function<ZooModel()> clone;
};

namespace detail {

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
  /// An operator, or an undefined one where the argument is None (null in case.json).
  nn::SparseOperator op_or_none(std::size_t i) const {
    return is_none(i) ? nn::SparseOperator() : op_of(at(i), i);
  }
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
  z.clone = [name, m, call, min_args, max_args] {
    M copy(std::dynamic_pointer_cast<typename M::ContainedType>(m->clone()));
    return wrap<M>(name, copy, call, min_args, max_args);
  };
  return z;
}

}  // namespace detail

}  // namespace topos::models::zoo

namespace topos::models {
// Deprecated: the zoo's old names. Write zoo::ZooArg (etc.).
using zoo::ZooArg;
using zoo::ZooModel;
}  // namespace topos::models
