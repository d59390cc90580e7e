// topos/testing/zoo_case.hpp
// Running a TopoModelX golden case (shared/reference/tdl-golden format): the model from
// case.json's "model" and "config", its weights from state_dict/ (or a torch .pt state_dict),
// the positional arguments from case.json's "forward" list (inputs/ tensors, operators by name,
// tuples/lists, None), in eval mode; and the parameter gradients of Σ_outputs Σ(out · R).
// The operators are built from complex.json and operators.json (case_operators), never read
// from the case's operators/ folder. Declarations only: the definitions (which build any of the
// zoo's models) are compiled once, in tests/support/src/zoo_case.cpp (CMake target
// topos_testing_zoo).
#pragma once

#include "topos/data/json.hpp"
#include "topos/data/npy.hpp"
#include "topos/models/state_dict.hpp"
#include "topos/testing/tdl_case.hpp"
#include "topos/models/zoo.hpp"
#include "topos/nn/serialization.hpp"

#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <vector>

namespace topos::models {

/// A case's model, its outputs' names and its arguments.
struct ZooCase {
  std::filesystem::path dir;
  nlohmann::json spec;
  ZooModel model;
  std::vector<ZooArg> args;
  std::vector<std::string> outputs;
};

/// Reads case.json, builds the model and loads its weights (eval mode), and the arguments, in
/// `dtype` (float64 by default: TopoModelX's float32 results carry rounding that cancellation in
/// deep polynomial filters amplifies; computing in double keeps ours to the exact value's side).
/// `operators` is called once the model and its weights are in place, so a bad model or config
/// is reported before the complex is read.
using OperatorSource = std::function<std::map<std::string, nn::SparseOperator>()>;
ZooCase load_case(const std::filesystem::path& dir, const OperatorSource& operator_source,
                  bool topomodelx_compatible = true, torch::Dtype dtype = torch::kDouble);
inline ZooCase load_case(const std::filesystem::path& dir,
                         const std::map<std::string, nn::SparseOperator>& operators,
                         bool topomodelx_compatible = true, torch::Dtype dtype = torch::kDouble) {
  return load_case(dir, OperatorSource([&operators] { return operators; }), topomodelx_compatible,
                   dtype);
}

/// Runs the case's forward; outputs by name (as many as case.json lists).
std::map<std::string, torch::Tensor> run_case(ZooCase& c);

/// Gradients of Σ_outputs Σ(out · R_out) (R from grads/_R_<out>.npy) for every parameter by
/// name; a parameter the outputs do not depend on gets zeros.
std::map<std::string, torch::Tensor> case_gradients(ZooCase& c);

/// The operators of a case, built from DIR/complex.json and DIR/operators.json's op/args
/// (topos/testing/tdl_case.hpp; never DIR/operators/), as float32 like the tensors TopoModelX got
/// (its operators were saved as float32 and passed as their nonzero entries).
std::map<std::string, nn::SparseOperator> case_operators(const std::filesystem::path& dir);

}  // namespace topos::models
