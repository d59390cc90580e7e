// topos/models/zoo/golden_case-inl.hpp
// The implementation of golden_case.hpp (documented there): compiled once into topos::zoo
// (src/zoo.cpp), or inline with TOPOS_HEADER_ONLY (topos/config.hpp). load_case builds the
// model by name (make_zoo_model: every model of the zoo) and the operators through tdl_case.hpp,
// which takes minutes in each translation unit that compiles it.
#pragma once

#include "topos/data/tdl_case.hpp"
#include "topos/models/zoo.hpp"
#include "topos/models/zoo/golden_case.hpp"

namespace topos::models::zoo {

namespace detail {

// One entry of case.json's "forward" list: an inputs/ tensor, an operator by name, a tuple, list
// or dict of entries, or null.
inline ZooArg case_argument(const nlohmann::json& e, const std::filesystem::path& dir,
                            const std::map<std::string, nn::SparseOperator>& ops,
                            torch::Dtype dtype) {
  if (e.is_null()) return ZooArg{};
  if (!e.is_object())
    throw ZooError("case.json: a forward entry must be an object or null, got " + e.dump());
  for (const char* k : {"tuple", "list"}) {
    if (e.contains(k)) {
      std::vector<ZooArg> items;
      for (const auto& x : e.at(k)) items.push_back(case_argument(x, dir, ops, dtype));
      return ZooArg::list(std::move(items));
    }
  }
  if (e.contains("dict")) {
    if (!e.at("dict").is_object()) throw ZooError("case.json: a dict entry must be an object");
    std::vector<ZooArg> items;
    for (const auto& [k, x] : e.at("dict").items()) {
      items.push_back(case_argument(x, dir, ops, dtype));
      items.back().key = k;
    }
    return ZooArg::dict(std::move(items));
  }
  const auto name = e.value("name", std::string());
  const auto from = e.value("from", std::string());
  if (from == "inputs")
    return ZooArg::of(read_npy_tensor(dir / "inputs" / (name + ".npy")).to(dtype), name);
  if (from == "operators") {
    auto it = ops.find(name);
    if (it == ops.end())
      throw ZooError("case.json: operator '" + name +
                     "' is not among the operators built from complex.json");
    return ZooArg::of(it->second, name);
  }
  throw ZooError("case.json: forward entry '" + name + "' has unknown source '" + from + "'");
}
}  // namespace detail

TOPOS_INLINE ZooCase load_case(const std::filesystem::path& dir,
                               const OperatorSource& operator_source, bool topomodelx_compatible,
                               torch::Dtype dtype) {
  ZooCase c;
  c.dir = dir;
  c.spec = data::read_json_file(dir / "case.json");
  if (!c.spec.contains("model") || !c.spec.at("model").is_string())
    throw ZooError((dir / "case.json").string() + ": no model (an operator-only case?)");
  c.model = make_zoo_model(c.spec.at("model").get<std::string>(),
                           c.spec.value("config", nlohmann::json::object()), topomodelx_compatible);
  load_state_dict(*c.model.module, dir / "state_dict");
  c.model.module->to(dtype);
  c.model.module->eval();
  if (c.spec.contains("kwargs") && !c.spec.at("kwargs").empty())
    throw ZooError(c.model.name + ": forward keyword arguments are not supported (" +
                   c.spec.at("kwargs").dump() + ")");
  const auto operators = operator_source();
  for (const auto& e : c.spec.at("forward"))
    c.args.push_back(detail::case_argument(e, dir, operators, dtype));
  c.outputs = c.spec.at("outputs").get<std::vector<std::string>>();
  return c;
}
TOPOS_INLINE std::map<std::string, torch::Tensor> run_case(ZooCase& c) {
  const auto out = c.model.forward(c.args);
  if (out.size() != c.outputs.size())
    throw ZooError(c.model.name + ": the model returns " + std::to_string(out.size()) +
                   " outputs, case.json names " + std::to_string(c.outputs.size()));
  std::map<std::string, torch::Tensor> named;
  for (std::size_t i = 0; i < out.size(); ++i) named[c.outputs[i]] = out[i];
  return named;
}

TOPOS_INLINE std::map<std::string, torch::Tensor> case_gradients(ZooCase& c) {
  auto& m = *c.model.module;
  for (auto& p : m.parameters()) p.mutable_grad() = torch::Tensor();
  const auto out = run_case(c);
  torch::Tensor loss = torch::zeros({}, torch::kDouble);
  for (const auto& [name, y] : out) {
    const auto R = read_npy_tensor(c.dir / "grads" / ("_R_" + name + ".npy"));
    if (R.sizes() != y.sizes())
      throw ZooError("grads/_R_" + name + ".npy: shape differs from the output's");
    loss = loss + (y * R.to(y.scalar_type())).sum();
  }
  loss.backward();
  std::map<std::string, torch::Tensor> g;
  for (const auto& p : m.named_parameters())
    g[p.key()] =
        p.value().grad().defined() ? p.value().grad().clone() : torch::zeros_like(p.value());
  return g;
}

TOPOS_INLINE ZooModel make_compiled_zoo_model(const std::string& model,
                                              const nlohmann::json& config,
                                              bool topomodelx_compatible) {
  return make_zoo_model(model, config, topomodelx_compatible);
}

TOPOS_INLINE std::vector<std::string> compiled_zoo_model_names() {
  return zoo_model_names();
}

TOPOS_INLINE std::map<std::string, nn::SparseOperator> case_operators(
    const std::filesystem::path& dir) {
  const data::Operators built = data::compute_operators(dir);
  std::map<std::string, nn::SparseOperator> ops;
  for (const auto& [name, m] : built.by_name)
    ops.emplace(name, nn::SparseOperator::from_eigen(m, torch::kFloat));
  return ops;
}

}  // namespace topos::models::zoo
