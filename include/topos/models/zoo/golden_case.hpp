// topos/models/zoo/golden_case.hpp
// Running a model case of the TDL golden format: a TopoModelX model saved with its weights,
// inputs and outputs (case.json, complex.json, operators.json, state_dict/, inputs/, grads/), so
// that topos's model is checked against TopoModelX's on the same numbers (the zoo's parity
// tests, `tdl forward` and `tdl grad`). The model comes from case.json's "model" and "config"
// (make_zoo_model, topos/models/zoo.hpp), its weights from state_dict/ (or a torch .pt
// state_dict), the positional arguments from case.json's "forward" list (inputs/ tensors,
// operators by name, tuples/lists, None), in eval mode; and the parameter gradients of
// Σ_outputs Σ(out · R). The operators are built from complex.json and operators.json
// (case_operators, topos/data/tdl_case.hpp), never read from the case's operators/ folder.
// This header declares; golden_case-inl.hpp implements (it builds any of the zoo's models),
// compiled once into topos::zoo (src/zoo.cpp), or inline with TOPOS_HEADER_ONLY
// (topos/config.hpp).
#pragma once

#include "topos/config.hpp"
#include "topos/data/json.hpp"
#include "topos/models/state_dict.hpp"
#include "topos/models/zoo/arguments.hpp"
#include "topos/nn/sparse_operator.hpp"

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <vector>

namespace topos::models::zoo {

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

/// make_zoo_model and zoo_model_names (topos/models/zoo.hpp) compiled once in topos::zoo: a
/// translation unit that calls these compiles none of the zoo's models (the Python binding's
/// topos.topomodelx does).
ZooModel make_compiled_zoo_model(const std::string& model, const nlohmann::json& config,
                                 bool topomodelx_compatible = true);
std::vector<std::string> compiled_zoo_model_names();

/// The operators of a case, built from DIR/complex.json and DIR/operators.json's op/args
/// (topos/data/tdl_case.hpp; never DIR/operators/), as float32 like the tensors TopoModelX got
/// (its operators were saved as float32 and passed as their nonzero entries).
std::map<std::string, nn::SparseOperator> case_operators(const std::filesystem::path& dir);

}  // namespace topos::models::zoo

namespace topos::models {
// Deprecated: the zoo's old names. Write zoo::load_case (etc.).
using zoo::case_gradients;
using zoo::case_operators;
using zoo::compiled_zoo_model_names;
using zoo::load_case;
using zoo::make_compiled_zoo_model;
using zoo::OperatorSource;
using zoo::run_case;
using zoo::ZooCase;
}  // namespace topos::models

#ifdef TOPOS_HEADER_ONLY
#include "topos/models/zoo/golden_case-inl.hpp"
#endif
