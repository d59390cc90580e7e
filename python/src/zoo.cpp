// python/src/zoo.cpp
// topos._C.zoo: the C++ model zoo (TopoModelX's models by class name, topos/models/zoo.hpp) for
// the drop-in package topos.topomodelx. A model is built from its TopoModelX constructor
// arguments (JSON, as make_zoo_model reads them) and run on TopoModelX's positional forward
// arguments (tensors, operators, tuples/lists/dicts of them, None) by the zoo's own argument
// mapping (topos/models/zoo/arguments.hpp); its parameters and buffers are the C++ module's
// tensors, which the Python module registers without a copy (topos.nn's sharing).

#include "convert.hpp"

#include "topos/models/zoo/golden_case.hpp"  // make_compiled_zoo_model: compiled in topos::zoo

#include <pybind11/stl.h>

#include <string>
#include <vector>

namespace topos::python {

namespace {

using models::zoo::ZooArg;
using models::zoo::ZooModel;

/// The dtype operators are converted to: the model's first floating parameter's.
at::ScalarType model_dtype(torch::nn::Module& m) {
  for (const auto& p : m.parameters())
    if (p.is_floating_point()) return p.scalar_type();
  return at::typeMetaToScalarType(at::get_default_dtype());
}

/// One positional forward argument. `where` names it in errors ("SCN2.forward(laplacian_0)").
ZooArg zoo_arg(const py::handle& obj, const std::string& where, at::ScalarType dtype) {
  if (obj.is_none()) return ZooArg{};
  if (py::isinstance<py::tuple>(obj) || py::isinstance<py::list>(obj)) {
    std::vector<ZooArg> items;
    std::size_t i = 0;
    for (const auto& x : obj)
      items.push_back(zoo_arg(x, where + "[" + std::to_string(i++) + "]", dtype));
    return ZooArg::list(std::move(items));
  }
  if (py::isinstance<py::dict>(obj)) {
    std::vector<ZooArg> items;
    for (const auto& [k, x] : obj.cast<py::dict>()) {
      if (!py::isinstance<py::str>(k))
        throw py::type_error(where + ": dict keys must be str, got a " + type_name(k));
      const auto key = k.cast<std::string>();
      items.push_back(zoo_arg(x, where + "['" + key + "']", dtype));
      items.back().key = key;
    }
    return ZooArg::dict(std::move(items));
  }
  if (THPVariable_Check(obj.ptr()) && py::cast<at::Tensor>(obj).layout() == at::kStrided)
    return ZooArg::of(py::cast<at::Tensor>(obj), where);
  return ZooArg::of(operator_arg(obj, where, dtype), where);
}

}  // namespace

void bind_zoo(py::module_& parent) {
  py::module_ m = parent.def_submodule(
      "zoo", "The C++ model zoo by TopoModelX class name (topos.topomodelx wraps it).");
  py::register_local_exception<models::zoo::ZooError>(m, "ZooError", PyExc_ValueError)
      .attr("__doc__") = "A zoo model's bad constructor or forward argument (named).";
  m.def("model_names", &models::zoo::compiled_zoo_model_names,
        "TopoModelX class names the zoo builds.");
  py::class_<ZooModel>(m, "_ZooModel", "A zoo model (topos.topomodelx wraps it in a Module).")
      .def(py::init([](const std::string& model, const std::string& config, bool compatible) {
             nlohmann::json j;
             try {
               j = nlohmann::json::parse(config);
             } catch (const nlohmann::json::exception& e) {
               throw models::zoo::ZooError(model + ": config is not JSON (" + e.what() + ")");
             }
             return models::zoo::make_compiled_zoo_model(model, j, compatible);
           }),
           py::arg("model"), py::arg("config"), py::arg("topomodelx_compatible"))
      .def(
          "tensors",
          [](ZooModel& z) {
            py::list out;
            for (const auto& p : z.module->named_parameters(true))
              out.append(py::make_tuple(p.key(), p.value(), false));
            for (const auto& b : z.module->named_buffers(true))
              out.append(py::make_tuple(b.key(), b.value(), true));
            return out;
          },
          "(path, tensor, is_buffer) for every parameter and buffer: the module's own tensors.")
      .def(
          "clone", [](const ZooModel& z) { return z.clone(); },
          "A deep copy: the same options, parameters, buffers and mode.")
      .def(
          "forward",
          [](ZooModel& z, const py::sequence& args, bool training) {
            const at::ScalarType dtype = model_dtype(*z.module);
            std::vector<ZooArg> a;
            for (std::size_t i = 0; i < args.size(); ++i)
              a.push_back(
                  zoo_arg(args[i], z.name + ".forward argument " + std::to_string(i), dtype));
            std::vector<torch::Tensor> y;
            {
              py::gil_scoped_release release;
              z.module->train(training);
              y = z.forward(a);
            }
            return y;
          },
          py::arg("args"), py::arg("training"),
          "Runs the model on TopoModelX's positional forward arguments; its outputs in order.");
}

}  // namespace topos::python
