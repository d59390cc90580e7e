// python/src/topobench.cpp
// topos._C.topobench: TopoBench's pipeline (topos/models/topobench/, compiled in
// topos::topobench) for the package topos.topobench: the raw TU / Planetoid readers, the
// liftings with their named operators, batches, the protocol (reproduce-hparams.txt, the
// splits), the trainer and the runs folder. A backbone is built by a Python callable per run:
// an OperatorSchedule (or a topos.nn.OperatorNetwork) runs in the C++ engine as the C++
// trainer's own backbones do; any other torch.nn.Module becomes a C++ module that holds the
// Python module's own parameters and buffers (so the C++ optimizer, early stopping's snapshot and
// train()/eval() act on them) and calls its forward under the GIL. Training releases the GIL.

#include "convert.hpp"

#include "topos/data/graph_datasets.hpp"
#include "topos/models/topobench/report.hpp"
#include "topos/models/topobench/table_models.hpp"  // model_specs, model_spec
#include "topos/models/topobench/trainer.hpp"

#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cstdlib>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace topos::python {

namespace {

namespace topobench = topos::models::topobench;
namespace fs = std::filesystem;

/// A Python object that C++ copies freely (std::function, Backbone, the model's options): the
/// reference count is touched once, under the GIL, when the last copy goes.
using PyRef = std::shared_ptr<py::object>;
PyRef hold(py::object o) {
  return PyRef(new py::object(std::move(o)), [](py::object* p) {
    py::gil_scoped_acquire gil;
    delete p;
  });
}

/// The datasets folder: `root`, or TOPOS_DATASETS_DIR (../shared/datasets' layout).
fs::path root_arg(const std::optional<fs::path>& root) {
  fs::path p;
  if (root) {
    p = *root;
  } else {
    const char* env = std::getenv("TOPOS_DATASETS_DIR");
    if (env == nullptr || *env == 0)
      throw py::value_error(
          "root: not given and TOPOS_DATASETS_DIR is not set; pass root= or set it to the folder "
          "holding tu/, dgcnn/, planetoid/ and topobench/ (docs/topobench.md)");
    p = env;
  }
  if (!fs::is_directory(p)) {
    PyErr_SetObject(PyExc_FileNotFoundError,
                    py::make_tuple(ENOENT, "root: no such datasets folder", p.string()).ptr());
    throw py::error_already_set();
  }
  return p;
}

topobench::Domain domain_arg(const std::string& d) {
  for (auto x : {topobench::Domain::graph, topobench::Domain::hypergraph, topobench::Domain::cell,
                 topobench::Domain::simplicial})
    if (d == topobench::domain_name(x)) return x;
  throw py::value_error("domain: '" + d + "' is not one of 'graph', 'hypergraph', 'cell', " +
                        "'simplicial'");
}

at::Tensor floats(const std::vector<float>& v, std::int64_t rows, std::int64_t cols) {
  return torch::tensor(v, torch::kFloat32).reshape({rows, cols});
}

at::Tensor edge_index(const std::vector<std::array<std::int64_t, 2>>& edges) {
  auto t = torch::empty({2, static_cast<std::int64_t>(edges.size())}, torch::kLong);
  auto a = t.accessor<std::int64_t, 2>();
  for (std::size_t e = 0; e < edges.size(); ++e)
    a[0][static_cast<std::int64_t>(e)] = edges[e][0],
    a[1][static_cast<std::int64_t>(e)] = edges[e][1];
  return t;
}

py::dict operators_out(const std::map<std::string, nn::SparseOperator>& ops) {
  py::dict d;
  for (const auto& [name, op] : ops) d[py::str(name)] = operator_out(op, "operator '" + name + "'");
  return d;
}

/// A lifted dataset with the name it was read under and the layout it was lifted for.
struct Lifted {
  std::shared_ptr<const topobench::LiftedDataset> data;
  std::string dataset;
  topobench::RankLayout layout;
};

std::vector<std::size_t> indices_arg(const py::handle& obj, std::int64_t size,
                                     const std::string& arg) {
  std::vector<std::size_t> out;
  for (const auto& i : obj) {
    if (!py::isinstance<py::int_>(i) &&
        !(THPVariable_Check(i.ptr()) && py::cast<at::Tensor>(i).numel() == 1 &&
          !py::cast<at::Tensor>(i).is_floating_point()))
      throw py::type_error(arg + ": expected integer indices, got a " + type_name(i));
    const auto v = py::int_(py::reinterpret_borrow<py::object>(i)).cast<std::int64_t>();
    if (v < 0 || v >= size)
      throw py::index_error(arg + ": index " + std::to_string(v) + " is outside [0, " +
                            std::to_string(size) + ")");
    out.push_back(static_cast<std::size_t>(v));
  }
  return out;
}

// ----- a Python module as the backbone ------------------------------------------------------

/// A torch.nn.Module backbone: its parameters and buffers registered (not copied) at their dotted
/// paths under empty C++ submodules, so `model.backbone.<path>` names the very tensors Python's
/// module reads; forward(x, operators) calls the module with dicts of tensors and torch sparse
/// COO operators under the GIL.
class PyBackboneImpl : public torch::nn::Module {
 public:
  PyBackboneImpl(PyRef module, std::string name)
      : module_(std::move(module)), name_(std::move(name)) {
    py::gil_scoped_acquire gil;
    for (const auto& [kind, method] :
         {std::pair<bool, const char*>{false, "named_parameters"}, {true, "named_buffers"}})
      for (const auto& item : module_->attr(method)()) {
        const auto pair = item.cast<py::tuple>();
        const auto path = pair[0].cast<std::string>();
        if (pair[1].is_none()) continue;
        const at::Tensor t = py::cast<at::Tensor>(pair[1]);
        torch::nn::Module* owner = this;
        std::string leaf = path;
        for (auto dot = leaf.find('.'); dot != std::string::npos; dot = leaf.find('.')) {
          const std::string part = leaf.substr(0, dot);
          leaf = leaf.substr(dot + 1);
          auto children = owner->named_children();
          auto* child = children.find(part);
          owner = child ? child->get()
                        : owner->register_module(part, std::make_shared<torch::nn::Module>()).get();
        }
        if (kind)
          owner->register_buffer(leaf, t);
        else
          owner->register_parameter(leaf, t, t.requires_grad());
        shared_.push_back({path, kind, t.unsafeGetTensorImpl()});
      }
  }

  const py::object& module() const { return *module_; }

  void train(bool on) override {
    torch::nn::Module::train(on);
    py::gil_scoped_acquire gil;
    module_->attr("train")(on);
  }

  topobench::NamedCochains forward(const topobench::NamedCochains& x,
                                   const topobench::NamedOperators& ops) {
    py::gil_scoped_acquire gil;
    check_shared();
    py::dict xs;
    for (const auto& [k, v] : x) xs[py::str(k)] = v;
    const py::object out = (*module_)(xs, operators_out(ops));
    if (!py::isinstance(out, py::module_::import("collections.abc").attr("Mapping")))
      throw py::type_error(name_ + ": the backbone's forward returned a " + type_name(out) +
                           "; expected a dict of name ('x_0', ...) -> tensor");
    topobench::NamedCochains y;
    for (const auto& [k, v] : out.cast<py::dict>()) {
      if (!py::isinstance<py::str>(k) || !THPVariable_Check(v.ptr()))
        throw py::type_error(name_ + ": the backbone's forward returned an entry " + type_name(k) +
                             " -> " + type_name(v) + "; expected name ('x_0', ...) -> tensor");
      y.emplace(k.cast<std::string>(), py::cast<at::Tensor>(v));
    }
    return y;
  }

 private:
  /// A parameter or buffer that Python's module replaced since would no longer be trained.
  void check_shared() const {
    std::map<std::string, const c10::TensorImpl*> now;
    for (const char* method : {"named_parameters", "named_buffers"})
      for (const auto& item : module_->attr(method)()) {
        const auto pair = item.cast<py::tuple>();
        if (!pair[1].is_none())
          now[pair[0].cast<std::string>()] = py::cast<at::Tensor>(pair[1]).unsafeGetTensorImpl();
      }
    for (const auto& s : shared_) {
      const auto it = now.find(s.path);
      if (it == now.end() || it->second != s.impl)
        throw py::value_error(
            name_ + ": the backbone's " + (s.buffer ? "buffer" : "parameter") + " '" + s.path +
            "' was replaced by another tensor during training, which the "
            "trainer does not see; update it in place (x.copy_(...), x.add_(...))");
    }
    if (now.size() != shared_.size())
      throw py::value_error(name_ +
                            ": the backbone gained parameters or buffers after it was built; "
                            "create them all in its constructor (make(ctx))");
  }

  struct Shared {
    std::string path;
    bool buffer;
    const c10::TensorImpl* impl;
  };
  PyRef module_;
  std::string name_;
  std::vector<Shared> shared_;
};
TORCH_MODULE(PyBackbone);

/// The C++ backbone of a Python recipe: make(ctx) returns an OperatorSchedule, a
/// topos.nn.OperatorNetwork, or any torch.nn.Module (called as forward(x, operators)).
topobench::Backbone backbone_arg(const std::string& name, const topobench::RankLayout& layout,
                                 py::object make) {
  if (!PyCallable_Check(make.ptr()))
    throw py::type_error("Backbone(make): expected a callable make(ctx), got a " + type_name(make));
  const PyRef fn = hold(std::move(make));
  return topobench::Backbone(name, layout, [fn, name, layout](const topobench::BackboneContext& c) {
    py::gil_scoped_acquire gil;
    const py::object made = (*fn)(c);
    const py::module_ nn_mod = py::module_::import("topos.nn");
    if (py::isinstance<nn::OperatorSchedule>(made) ||
        py::isinstance(made, nn_mod.attr("OperatorNetwork"))) {
      nn::OperatorNetwork net =
          py::isinstance<nn::OperatorSchedule>(made)
              ? nn::OperatorNetwork(made.cast<nn::OperatorSchedule>())
              : nn::OperatorNetwork(
                    made.attr("_network").cast<std::shared_ptr<nn::OperatorNetworkImpl>>());
      return topobench::Backbone::network(name, layout,
                                          [net](const topobench::BackboneContext&) { return net; })
          .build(c);
    }
    if (!py::isinstance(made, py::module_::import("torch").attr("nn").attr("Module")))
      throw py::type_error(name + ": make(ctx) returned a " + type_name(made) +
                           "; expected a topos.nn.OperatorSchedule, a topos.nn.OperatorNetwork or "
                           "a torch.nn.Module whose forward(x, operators) returns a dict");
    PyBackbone module(hold(made), name);
    return topobench::Backbone::module(
               name, layout, [module](const topobench::BackboneContext&) { return module; })
        .build(c);
  });
}

using Model = topobench::TopoBenchModelImpl;

std::shared_ptr<Model> shared_model(Model& m) {
  return std::dynamic_pointer_cast<Model>(m.shared_from_this());
}

py::dict state_dict(Model& m) {
  py::dict d;
  for (const auto& p : m.named_parameters()) d[py::str(p.key())] = p.value();
  for (const auto& b : m.named_buffers()) d[py::str(b.key())] = b.value();
  return d;
}

// ----- bindings ---------------------------------------------------------------------------------

void bind_protocol(py::module_& m) {
  py::class_<topobench::RankLayout>(
      m, "RankLayout",
      "What a backbone works on: the domain the data is lifted to, the "
      "ranks the encoder gives it, how many ranks it returns, and the "
      "operators (lifting names) it and the readout read.")
      .def(py::init([](const std::string& domain, std::vector<int> encoded_ranks,
                       int cell_dimensions, std::set<std::string> operators) {
             topobench::RankLayout l;
             l.domain = domain_arg(domain);
             l.encoded_ranks = std::move(encoded_ranks);
             l.cell_dimensions = cell_dimensions;
             l.operators = std::move(operators);
             if (l.cell_dimensions < 1)
               throw py::value_error("RankLayout(cell_dimensions): must be at least 1, got " +
                                     std::to_string(l.cell_dimensions));
             return l;
           }),
           py::arg("domain"), py::arg("encoded_ranks"), py::arg("cell_dimensions"),
           py::arg("operators"))
      .def_property_readonly(
          "domain", [](const topobench::RankLayout& l) { return topobench::domain_name(l.domain); })
      .def_readonly("encoded_ranks", &topobench::RankLayout::encoded_ranks)
      .def_readonly("cell_dimensions", &topobench::RankLayout::cell_dimensions)
      .def_readonly("operators", &topobench::RankLayout::operators)
      .def("__repr__", [](const topobench::RankLayout& l) {
        return py::str(
                   "RankLayout(domain={!r}, encoded_ranks={}, cell_dimensions={}, "
                   "operators={})")
            .format(topobench::domain_name(l.domain), py::cast(l.encoded_ranks), l.cell_dimensions,
                    py::cast(l.operators));
      });

  m.def("models", [] {
    std::vector<std::string> n;
    for (const auto& s : topobench::model_specs()) n.push_back(s.name);
    return n;
  });
  m.def("datasets", [] {
    std::vector<std::string> n;
    for (const auto& d : topobench::table_datasets()) n.push_back(d.name);
    return n;
  });
  m.def(
      "model_layout",
      [](const std::string& model) { return topobench::rank_layout(topobench::model_spec(model)); },
      py::arg("model"), "The RankLayout of one of the table's models (CWN, SCN, ...).");

  py::class_<topobench::RunConfig>(
      m, "RunConfig", "One (model, dataset) line of reproduce-hparams.txt (fields writable).")
      .def(py::init<>())
      .def_readwrite("model_config", &topobench::RunConfig::model_config)
      .def_readwrite("dataset_config", &topobench::RunConfig::dataset_config)
      .def_readwrite("lr", &topobench::RunConfig::lr)
      .def_readwrite("dropout", &topobench::RunConfig::dropout)
      .def_readwrite("hidden", &topobench::RunConfig::hidden)
      .def_readwrite("layers", &topobench::RunConfig::layers)
      .def_readwrite("batch_size", &topobench::RunConfig::batch_size)
      .def_readwrite("readout", &topobench::RunConfig::readout)
      .def_readwrite("data_seeds", &topobench::RunConfig::data_seeds)
      .def_readwrite("max_epochs", &topobench::RunConfig::max_epochs)
      .def_readwrite("min_epochs", &topobench::RunConfig::min_epochs)
      .def_readwrite("val_every", &topobench::RunConfig::val_every)
      .def_readwrite("patience", &topobench::RunConfig::patience)
      .def_readwrite("signed_incidence", &topobench::RunConfig::signed_incidence)
      .def_readwrite("max_cell_length", &topobench::RunConfig::max_cell_length)
      .def_readwrite("source", &topobench::RunConfig::source)
      .def("__repr__", [](const topobench::RunConfig& c) {
        std::ostringstream o;
        o << "RunConfig(" << c.model_config << " " << c.dataset_config << ": lr=" << c.lr
          << " hidden=" << c.hidden << " layers=" << c.layers << " batch_size=" << c.batch_size
          << " dropout=" << c.dropout << " readout=" << (c.readout.empty() ? "-" : c.readout)
          << " epochs=" << c.min_epochs << ".." << c.max_epochs << " val_every=" << c.val_every
          << " patience=" << c.patience << ")";
        return o.str();
      });
  m.def("read_hparams", &topobench::read_hparams, py::arg("path"),
        "Every line of a reproduce-hparams.txt file (a malformed one is a DataError naming it).");
  m.def(
      "find_config",
      [](const std::string& model, const std::string& dataset,
         const std::optional<fs::path>& hparams, const std::optional<fs::path>& root) {
        const auto& spec = topobench::model_spec(model);
        const auto& d = topobench::dataset_name(dataset);
        const fs::path file =
            hparams ? *hparams : root_arg(root) / "topobench" / "reproduce-hparams.txt";
        return topobench::find_config(topobench::read_hparams(file), spec, d);
      },
      py::arg("model"), py::arg("dataset"), py::arg("hparams") = py::none(),
      py::arg("root") = py::none());
  m.def(
      "split",
      [](std::int64_t n, std::int64_t seed) {
        if (n < 0) throw py::value_error("split(n): must be >= 0, got " + std::to_string(n));
        const auto s = topobench::random_split(n, seed);
        return py::make_tuple(s.train, s.val, s.test);
      },
      py::arg("n"), py::arg("seed"));

  py::class_<topobench::RunResult>(m, "RunResult", "One finished run: a row of runs.csv.")
      .def_readonly("model", &topobench::RunResult::model)
      .def_readonly("dataset", &topobench::RunResult::dataset)
      .def_readonly("split_seed", &topobench::RunResult::split_seed)
      .def_readonly("test_accuracy", &topobench::RunResult::test_accuracy)
      .def_readonly("best_epoch", &topobench::RunResult::best_epoch)
      .def_readonly("epochs", &topobench::RunResult::epochs)
      .def_readonly("seconds", &topobench::RunResult::seconds)
      .def("__repr__", [](const topobench::RunResult& r) {
        return py::str(
                   "RunResult({} {} split {}: test_accuracy={:.4f}, best_epoch={}, "
                   "epochs={})")
            .format(r.model, r.dataset, r.split_seed, r.test_accuracy, r.best_epoch, r.epochs);
      });
  py::class_<topobench::Check>(m, "Check",
                               "One validation check: epoch, mean training loss, accuracy.")
      .def_readonly("epoch", &topobench::Check::epoch)
      .def_readonly("loss", &topobench::Check::loss)
      .def_readonly("val_accuracy", &topobench::Check::val_accuracy)
      .def("__repr__", [](const topobench::Check& c) {
        return py::str("Check(epoch={}, loss={:.4f}, val_accuracy={:.4f})")
            .format(c.epoch, c.loss, c.val_accuracy);
      });

  py::class_<topobench::RunsFolder>(
      m, "RunsFolder",
      "runs.csv, curves.csv, summary.csv, index.html and table.md of a "
      "folder of runs, resumable (done) and rewritten after every add.")
      .def(py::init<fs::path>(), py::arg("path"))
      .def_property_readonly("path", &topobench::RunsFolder::path)
      .def_property_readonly("runs", &topobench::RunsFolder::runs)
      .def("done", &topobench::RunsFolder::done, py::arg("model"), py::arg("dataset"),
           py::arg("seed"))
      .def(
          "add",
          [](topobench::RunsFolder& f, const topobench::RunResult& r,
             const std::vector<topobench::Check>& curve) { f.add(r, curve); },
          py::arg("result"), py::arg("curve"))
      .def("write_reports", [](const topobench::RunsFolder& f) { f.write_reports(); });
}

void bind_data(py::module_& m) {
  m.def(
      "read_dataset",
      [](const std::string& name, const std::optional<fs::path>& root) {
        const auto& d = topobench::dataset_name(name);
        const fs::path dir = root_arg(root);
        py::dict out;
        out["name"] = d.name;
        if (d.node_level) {
          data::NodeClassificationDataset ds;
          {
            py::gil_scoped_release release;
            ds = data::load_topobench_node_dataset(dir, d.name);
          }
          out["num_classes"] = ds.num_classes;
          out["num_node_features"] = ds.num_node_features;
          out["num_nodes"] = ds.num_nodes;
          out["x"] = floats(ds.x, ds.num_nodes, ds.num_node_features);
          out["edge_index"] = edge_index(ds.edges);
          out["labels"] = torch::tensor(ds.labels, torch::kLong);
          return out;
        }
        data::GraphClassificationDataset ds;
        {
          py::gil_scoped_release release;
          ds = data::load_topobench_graph_dataset(dir, d.name);
        }
        out["num_classes"] = ds.num_classes;
        out["num_node_features"] = ds.num_node_features;
        py::list graphs;
        for (const auto& g : ds.graphs) {
          py::dict gd;
          gd["num_nodes"] = g.num_nodes;
          gd["x"] = floats(g.x, g.num_nodes, ds.num_node_features);
          gd["edge_index"] = edge_index(g.edges);
          gd["edge_labels"] = torch::tensor(g.edge_labels, torch::kLong);
          gd["label"] = g.label;
          graphs.append(gd);
        }
        out["graphs"] = graphs;
        return out;
      },
      py::arg("name"), py::arg("root") = py::none(),
      "A dataset of TopoBench's table from its raw files, with TopoBench's node features.");

  py::class_<topobench::Batch>(m, "Batch", "Lifted graphs as one block-diagonal union.")
      .def_readonly("x", &topobench::Batch::x)
      .def_readonly("batch", &topobench::Batch::batch)
      .def_readonly("labels", &topobench::Batch::labels)
      .def_readonly("num_graphs", &topobench::Batch::num_graphs)
      .def_property_readonly("operators",
                             [](const topobench::Batch& b) { return operators_out(b.operators); });

  py::class_<Lifted>(m, "LiftedDataset", "A dataset lifted for one RankLayout.")
      .def("__len__", [](const Lifted& l) { return l.data->size(); })
      .def_readonly("dataset", &Lifted::dataset)
      .def_readonly("layout", &Lifted::layout)
      .def_property_readonly("num_classes", [](const Lifted& l) { return l.data->num_classes; })
      .def_property_readonly("node_level", [](const Lifted& l) { return l.data->node_level; })
      .def_property_readonly("num_graphs", [](const Lifted& l) { return l.data->graphs.size(); })
      .def_property_readonly("seconds", [](const Lifted& l) { return l.data->seconds; })
      .def_property_readonly("in_channels",
                             [](const Lifted& l) { return l.data->graphs.at(0).widths; })
      .def(
          "graph",
          [](const Lifted& l, std::int64_t i) {
            const auto n = static_cast<std::int64_t>(l.data->graphs.size());
            if (i < 0 || i >= n)
              throw py::index_error("graph(i): " + std::to_string(i) + " is outside [0, " +
                                    std::to_string(n) + ")");
            const auto b = topobench::collate(l.data->graphs, {static_cast<std::size_t>(i)});
            py::dict d;
            d["sizes"] = l.data->graphs[static_cast<std::size_t>(i)].sizes;
            d["x"] = b.x;
            d["operators"] = operators_out(b.operators);
            d["label"] = l.data->graphs[static_cast<std::size_t>(i)].label;
            return d;
          },
          py::arg("i"), "One lifted graph: cells per rank, features per rank, operators, class.")
      .def(
          "batch",
          [](const Lifted& l, const py::object& indices) {
            const auto which = indices_arg(
                indices, static_cast<std::int64_t>(l.data->graphs.size()), "batch(indices)");
            py::gil_scoped_release release;
            return topobench::collate(l.data->graphs, which);
          },
          py::arg("indices"))
      .def(
          "majority_accuracy",
          [](const Lifted& l, std::int64_t seed) {
            return topobench::majority_accuracy(*l.data, seed);
          },
          py::arg("seed"),
          "The test accuracy of predicting the training split's most frequent class.");

  m.def(
      "lift_dataset",
      [](const std::string& dataset, const topobench::RankLayout& layout,
         const topobench::RunConfig& cfg, const std::optional<fs::path>& root, bool factored,
         bool progress) {
        const auto& d = topobench::dataset_name(dataset);
        const fs::path dir = root_arg(root);
        // The lifting builds the names it knows and skips others: name one it does not know.
        topobench::GraphLiftingOptions all;  // no operators named: every one of the domain
        const auto known = topobench::lift_graph(3, {{0, 1}, {0, 2}, {1, 2}}, {1, 1, 1}, 1, {},
                                                 layout.domain, all);
        for (const auto& op : layout.operators)
          if (!known.operators.count(op)) {
            std::string names;
            for (const auto& [name, _] : known.operators)
              names += (names.empty() ? "" : ", ") + name;
            throw py::value_error("lift(layout): the " +
                                  std::string(topobench::domain_name(layout.domain)) +
                                  " lifting has no operator '" + op + "' (it has: " + names + ")");
          }
        Lifted l{nullptr, d.name, layout};
        {
          py::gil_scoped_release release;
          l.data = std::make_shared<const topobench::LiftedDataset>(
              topobench::lift_dataset(dir, d, layout, cfg, factored, progress));
        }
        return l;
      },
      py::arg("dataset"), py::arg("layout"), py::arg("config"), py::arg("root") = py::none(),
      py::arg("factored") = false, py::arg("progress") = false);
}

void bind_training(py::module_& m) {
  py::class_<topobench::BackboneContext>(m, "BackboneContext",
                                         "What a backbone is built for: hidden (its width on every "
                                         "rank), n_layers, topobench_compatible.")
      .def_readonly("hidden", &topobench::BackboneContext::hidden)
      .def_readonly("n_layers", &topobench::BackboneContext::n_layers)
      .def_readonly("topobench_compatible", &topobench::BackboneContext::topobench_compatible);

  py::class_<Model, std::shared_ptr<Model>>(
      m, "Model",
      "TopoBench's model around the backbone: encoder, backbone, wrapper, readout, classifier.")
      .def(
          "__call__",
          [](Model& net, const topobench::Batch& b) {
            py::gil_scoped_release release;
            return net.forward(b);
          },
          py::arg("batch"), "Logits: one row per graph (graph-level) or per node.")
      .def("state_dict", &state_dict,
           "name -> tensor: the model's own parameters and buffers (a Python backbone's under "
           "'backbone.').")
      .def(
          "train", [](Model& net, bool on) { net.train(on); }, py::arg("mode") = true)
      .def("eval", [](Model& net) { net.eval(); })
      .def_property_readonly("training", [](const Model& net) { return net.is_training(); })
      .def_property_readonly("name", [](const Model& net) { return net.options.model(); })
      .def_property_readonly(
          "backbone",
          [](Model& net) -> py::object {
            for (const auto& c : net.named_children())
              if (c.key() == "backbone")
                if (auto p = std::dynamic_pointer_cast<PyBackboneImpl>(c.value()))
                  return p->module();
            return py::none();
          },
          "The Python backbone module (None for a schedule's).")
      .def(
          "accuracy",
          [](Model& net, const Lifted& data, const py::object& indices, std::size_t batch_size) {
            const auto part = indices_arg(indices, data.data->size(), "accuracy(indices)");
            if (batch_size == 0) throw py::value_error("accuracy(batch_size): must be positive");
            py::gil_scoped_release release;
            return topobench::EvalSet(*data.data, part, batch_size).accuracy(net);
          },
          py::arg("data"), py::arg("indices"), py::arg("batch_size") = 64,
          "Accuracy on graphs (or nodes) `indices` of `data`, in eval mode.");

  m.def(
      "check_backbone",
      [](const std::string& name, const topobench::RankLayout& layout) {
        topobench::Backbone(name, layout, [](const topobench::BackboneContext&) {
          return topobench::BuiltBackbone{};
        });
      },
      py::arg("name"), py::arg("layout"),
      "Raises ValueError where topobench::Backbone refuses the name or the layout.");
  m.def(
      "train_run",
      [](const Lifted& data, const std::string& name, const topobench::RankLayout& layout,
         py::object make, const topobench::RunConfig& cfg, std::int64_t seed, int max_epochs,
         bool progress, py::object on_check, bool flush_denormals) {
        const topobench::Backbone backbone = backbone_arg(name, layout, std::move(make));
        topobench::TrainOptions o;
        o.max_epochs = max_epochs;
        o.progress = progress;
        o.flush_denormals = flush_denormals;
        if (!on_check.is_none()) {
          const PyRef cb = hold(std::move(on_check));
          o.on_check = [cb](const topobench::Check& c, Model& net) {
            py::gil_scoped_acquire gil;
            (*cb)(c, shared_model(net));
          };
        }
        topobench::TrainedRun run;
        {
          py::gil_scoped_release release;
          run = topobench::train_run(*data.data, backbone, data.dataset, cfg, seed, o);
        }
        py::dict out;
        out["result"] = run.result;
        out["curve"] = run.curve;
        out["best_val_accuracy"] = run.best_val_accuracy;
        out["model"] = run.model.ptr();
        return out;
      },
      py::arg("data"), py::arg("name"), py::arg("layout"), py::arg("make"), py::arg("config"),
      py::arg("seed"), py::arg("max_epochs") = 0, py::arg("progress") = false,
      py::arg("on_check") = py::none(), py::arg("flush_denormals") = true);
}

}  // namespace

void bind_topobench(py::module_& parent) {
  py::module_ m = parent.def_submodule(
      "topobench", "TopoBench's pipeline (the package topos.topobench wraps it).");
  bind_protocol(m);
  bind_data(m);
  bind_training(m);
}

}  // namespace topos::python
