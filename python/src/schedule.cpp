// python/src/schedule.cpp
// topos._C.nn: the operator schedule from Python. The builder's vocabulary (OperatorSchedule,
// into/from_ steps and terms, their operations) bound as it is in C++; OperatorNetwork built from
// a schedule and run with the GIL released (python/topos/nn.py wraps it in a torch.nn.Module
// whose Parameters are the C++ network's own tensors); operations written in Python (an object
// with infer and forward) held by a C++ Operation that takes the GIL to call them. Operators
// come in as torch sparse COO / CSR tensors, scipy.sparse matrices or prepared SparseOperators.
#include "convert.hpp"

#include "topos/nn/cpu.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <ATen/ops/_sparse_coo_tensor_unsafe.h>
#include <pybind11/stl.h>

#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace topos::python {

using namespace topos::nn;

namespace {

PyObject* schedule_error_type = nullptr;  // topos.ScheduleError (set once, at import)

// ----- arguments ------------------------------------------------------------------------------

/// A cochain: a rank, or a (rank, state) pair.
CochainKey key_arg(const py::handle& obj, const std::string& arg) {
  if (py::isinstance<py::int_>(obj)) return {obj.cast<int>(), ""};
  if (py::isinstance<py::tuple>(obj) || py::isinstance<py::list>(obj)) {
    const auto s = obj.cast<py::sequence>();
    if (s.size() == 2 && py::isinstance<py::int_>(s[0]) && py::isinstance<py::str>(s[1]))
      return {s[0].cast<int>(), s[1].cast<std::string>()};
  }
  throw py::type_error(arg + ": expected a cochain as a rank (int) or a (rank, state) pair, got " +
                       type_name(obj));
}

/// Key weights: a (path, channels per head) or (path, channels, gain) tuple.
KeyWeights key_weights_arg(const py::handle& obj, const std::string& arg) {
  if (py::isinstance<py::tuple>(obj) || py::isinstance<py::list>(obj)) {
    const auto s = obj.cast<py::sequence>();
    if ((s.size() == 2 || s.size() == 3) && py::isinstance<py::str>(s[0]) &&
        py::isinstance<py::int_>(s[1]) && !py::isinstance<py::bool_>(s[1]) &&
        (s.size() == 2 || py::isinstance<py::float_>(s[2]) || py::isinstance<py::int_>(s[2]))) {
      KeyWeights k(s[0].cast<std::string>(), s[1].cast<std::int64_t>());
      if (s.size() == 3) k.gain(s[2].cast<double>());
      return k;
    }
  }
  throw py::type_error(arg +
                       ": expected (path, channels per head) or (path, channels, gain), e.g. "
                       "('att.K_weight', 16), got " +
                       type_name(obj));
}

py::tuple key_out(const CochainKey& k) {
  return py::make_tuple(k.rank, k.state);
}

/// An activation: topos.nn.Activation.relu, or its name ("relu", "elu", ..., "none").
Activation activation_arg(const py::handle& obj, const std::string& arg) {
  if (py::isinstance<Activation>(obj)) return obj.cast<Activation>();
  if (py::isinstance<py::str>(obj)) {
    try {
      return activation_from_string(obj.cast<std::string>());
    } catch (const std::invalid_argument& e) {
      throw py::value_error(arg + ": " + e.what());
    }
  }
  throw py::type_error(arg +
                       ": expected a topos.nn.Activation or its name ('relu', 'elu', ...), got " +
                       type_name(obj));
}

}  // namespace

SparseOperator operator_arg(const py::handle& obj, const std::string& arg, at::ScalarType dtype) {
  if (py::isinstance<SparseOperator>(obj)) return obj.cast<SparseOperator>();
  if (THPVariable_Check(obj.ptr())) {
    const at::Tensor t = py::cast<at::Tensor>(obj);
    if (t.layout() == at::kStrided)
      throw py::type_error(arg +
                           ": expected a sparse operator, got a dense torch.Tensor of shape " +
                           c10::str(t.sizes()) + "; pass A.to_sparse() (COO) or A.to_sparse_csr()");
    if (t.dim() != 2)
      throw py::value_error(arg + ": expected a 2-D sparse matrix, got " + std::to_string(t.dim()) +
                            " dimensions");
    if (t.layout() == at::kSparse) {
      const at::Tensor c = t.is_coalesced() ? t : t.coalesce();  // row-major, unique
      if (c._values().dim() != 1)
        throw py::value_error(arg + ": a hybrid sparse tensor (dense values per entry) is not a " +
                              "matrix");
      const at::Tensor idx = c._indices();
      return SparseOperator::from_sorted(t.size(0), t.size(1), index_vector(idx[0]),
                                         index_vector(idx[1]), c.values());
    }
    if (t.layout() == at::kSparseCsr) {
      // Through a coalesced COO tensor: a CSR tensor built without checking its invariants may
      // hold a row's columns out of order or repeated (repeats are summed, as in COO).
      const at::Tensor crow = t.crow_indices().to(at::kCPU, at::kLong);
      const at::Tensor counts = crow.narrow(0, 1, t.size(0)) - crow.narrow(0, 0, t.size(0));
      const at::Tensor rows = at::arange(t.size(0), crow.options()).repeat_interleave(counts);
      const at::Tensor c =
          at::sparse_coo_tensor(
              at::stack({rows, t.col_indices().to(at::kCPU, at::kLong)}).to(t.values().device()),
              t.values(), {t.size(0), t.size(1)})
              .coalesce();
      const at::Tensor idx = c._indices();
      return SparseOperator::from_sorted(t.size(0), t.size(1), index_vector(idx[0]),
                                         index_vector(idx[1]), c._values());
    }
    throw py::type_error(arg + ": a torch tensor of layout " + c10::str(t.layout()) +
                         " is not an operator; pass a sparse COO or CSR tensor");
  }
  if (py::hasattr(obj, "tocsr") && py::hasattr(obj, "nnz"))  // scipy.sparse
    return SparseOperator::from_eigen(sparse_arg(obj, arg), dtype);
  throw py::type_error(arg + ": expected a sparse operator (a torch sparse COO or CSR tensor, a " +
                       "scipy.sparse matrix or a topos.nn.SparseOperator), got " + type_name(obj));
}

at::Tensor operator_out(const SparseOperator& a, const std::string& who) {
  a.require_entries(who);
  const at::Tensor idx = at::stack({a.row, a.col});
  at::Tensor t = at::_sparse_coo_tensor_unsafe(idx, a.values, {a.rows, a.cols},
                                               a.values.options().layout(at::kSparse));
  t._coalesced_(true);
  return t;
}

namespace {

// ----- operations written in Python ----------------------------------------------------------

/// The context an operation's infer or forward is given, valid during that call only (a
/// reference kept past it is an error, not a dangling pointer).
template <class Context>
struct ContextRef {
  Context* ctx = nullptr;
  Context& get() const {
    if (ctx == nullptr)
      throw std::runtime_error(
          "this context belonged to one call of infer or forward and is no longer valid; use the "
          "context the current call is given");
    return *ctx;
  }
};
using BuildRef = ContextRef<BuildContext>;
using RunRef = ContextRef<RunContext>;

/// Calls `f(ref)` with a context reference that is invalidated when it returns.
template <class Context, class F>
py::object with_context(Context& ctx, F&& f) {
  auto ref = std::make_shared<ContextRef<Context>>();
  ref->ctx = &ctx;
  struct Reset {
    ContextRef<Context>& r;
    ~Reset() { r.ctx = nullptr; }
  } reset{*ref};
  return f(py::cast(ref));
}

/// An Operation whose str, infer, forward and traits are a Python object's methods (infer and
/// forward required, str and traits optional), called with the GIL taken.
class PythonOperation final : public Operation {
 public:
  explicit PythonOperation(py::object op) : op_(std::move(op)) {
    name_ = py::str(py::type::handle_of(op_).attr("__qualname__"));
    for (const char* m : {"infer", "forward"})
      if (!py::hasattr(op_, m) || !PyCallable_Check(op_.attr(m).ptr()))
        throw py::type_error("apply: " + type_name(op_) + " has no method " + m +
                             "(ctx, x); an operation defines infer(ctx, x) -> TermShape and "
                             "forward(ctx, x) -> torch.Tensor (topos.nn.Operation)");
  }
  ~PythonOperation() override {
    if (!Py_IsInitialized()) {  // at interpreter exit: nothing left to release it to
      op_.release();
      return;
    }
    py::gil_scoped_acquire gil;
    op_ = py::object();
  }

  std::string str(const std::string& x) const override {
    py::gil_scoped_acquire gil;
    try {  // also called while an error message is written: never raises
      if (py::hasattr(op_, "str")) return py::str(op_.attr("str")(x));
    } catch (py::error_already_set&) {
    }
    return name_ + "(" + x + ")";
  }

  TermShape infer(BuildContext& ctx, TermShape x) const override {
    py::gil_scoped_acquire gil;
    py::object r = call(ctx, "infer", [&] {
      return with_context(ctx, [&](py::object c) { return op_.attr("infer")(c, x); });
    });
    if (py::isinstance<TermShape>(r)) return r.cast<TermShape>();
    if (py::isinstance<py::tuple>(r) && py::len(r) == 2) {
      const auto t = r.cast<py::tuple>();
      if (py::isinstance<py::int_>(t[0]) && py::isinstance<py::int_>(t[1]))
        return {t[0].cast<int>(), t[1].cast<std::int64_t>()};
    }
    ctx.fail("python operation " + name_ + ".infer returned a " + type_name(r) +
             "; return a topos.nn.TermShape(rank, channels) (or x itself when both are kept)");
  }

  torch::Tensor forward(RunContext& ctx, const torch::Tensor& x) const override {
    py::gil_scoped_acquire gil;
    py::object r = call(ctx, "forward", [&] {
      return with_context(ctx, [&](py::object c) { return op_.attr("forward")(c, x); });
    });
    if (!THPVariable_Check(r.ptr()))
      ctx.fail("python operation " + name_ + ".forward returned a " + type_name(r) +
               ", not a torch.Tensor");
    return py::cast<at::Tensor>(r);
  }

  OperationTraits traits() const override {
    py::gil_scoped_acquire gil;
    if (!py::hasattr(op_, "traits")) return {};
    py::object r = op_.attr("traits")();
    if (r.is_none()) return {};
    if (!py::isinstance<OperationTraits>(r))
      throw py::type_error("python operation " + name_ + ".traits() returned a " + type_name(r) +
                           "; return a topos.nn.OperationTraits (or None: no promises)");
    return r.cast<OperationTraits>();
  }

 private:
  // `f()`; a Python exception from it is raised as a topos.ScheduleError naming the step and the
  // operation, the original as its __cause__ (a ScheduleError, which names the step already,
  // passes as it is).
  template <class Context, class F>
  py::object call(Context& ctx, const char* method, F&& f) const {
    try {
      return f();
    } catch (py::error_already_set& e) {
      if (e.matches(schedule_error_type)) throw;
      const std::string what = ctx.where() + ": python operation " + name_ + "." + method +
                               " raised " + std::string(py::str(e.type().attr("__name__"))) + ": " +
                               std::string(py::str(e.value()));
      py::raise_from(e, schedule_error_type, what.c_str());
      throw py::error_already_set();
    }
  }

  py::object op_;
  std::string name_;
};

// ----- the builder ---------------------------------------------------------------------------

constexpr auto self_ref = py::return_value_policy::reference;  // the same Python object back

/// The terms of sum / mean / concat / filter: terms as arguments, or one list of them.
std::vector<ops::Term> terms_arg(const py::args& args, const std::string& where) {
  std::vector<py::handle> items;
  if (args.size() == 1 && (py::isinstance<py::list>(args[0]) || py::isinstance<py::tuple>(args[0])))
    for (auto t : args[0].cast<py::sequence>()) items.push_back(t);
  else
    for (auto t : args) items.push_back(t);
  std::vector<ops::Term> terms;
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (!py::isinstance<ops::Term>(items[i]))
      throw py::type_error(where + ": term " + std::to_string(i + 1) + " is a " +
                           type_name(items[i]) + ", not a term (write from_(rank).via(...) ...)");
    terms.push_back(items[i].cast<ops::Term>());
  }
  return terms;
}

/// The operations a term and a step share (ops::Chain), on either class.
template <class D>
void bind_chain(py::class_<D>& c) {
  c.def(
       "via",
       [](D& d, std::string op, bool row_norm) -> D& { return d.via(std::move(op), row_norm); },
       py::arg("op"), py::arg("row_norm") = false, self_ref, "A · x (row_norm: / A's row sums).")
      .def(
          "via_t",
          [](D& d, std::string op, bool row_norm) -> D& {
            return d.via_t(std::move(op), row_norm);
          },
          py::arg("op"), py::arg("row_norm") = false, self_ref, "Aᵀ · x.")
      .def(
          "pattern", [](D& d, std::string op, Aggr a) -> D& { return d.pattern(std::move(op), a); },
          py::arg("op"), py::arg("aggr") = Aggr::sum, self_ref,
          "Sum (or mean) over A's sparsity pattern, its values ignored.")
      .def(
          "weight",
          [](D& d, std::string path, std::int64_t out, double gain) -> D& {
            return d.weight(std::move(path), out, gain);
          },
          py::arg("path"), py::arg("out"), py::arg("gain") = 1.414, self_ref,
          "x · W, W (in × out) at path, Glorot-initialised.")
      .def(
          "conv",
          [](D& d, const std::string& path, std::int64_t out) -> D& { return d.conv(path, out); },
          py::arg("path"), py::arg("out"), self_ref,
          "TopoModelX's Conv weight: weight(path + '.weight', out).")
      .def(
          "linear",
          [](D& d, std::string path, std::int64_t out, bool bias) -> D& {
            return d.linear(std::move(path), out, bias);
          },
          py::arg("path"), py::arg("out"), py::arg("bias") = true, self_ref,
          "torch.nn.Linear at path.")
      .def(
          "act",
          [](D& d, const py::object& u, double slope) -> D& {
            return d.act(activation_arg(u, "act(activation)"), slope);
          },
          py::arg("activation"), py::arg("negative_slope") = 0.01, self_ref,
          "An activation: Activation.relu or its name.")
      .def(
          "dropout", [](D& d, double p) -> D& { return d.dropout(p); }, py::arg("p"), self_ref)
      .def(
          "unit_rows", [](D& d) -> D& { return d.unit_rows(); }, self_ref)
      .def(
          "batch_norm", [](D& d, std::string path) -> D& { return d.batch_norm(std::move(path)); },
          py::arg("path"), self_ref)
      .def(
          "layer_norm", [](D& d, std::string path) -> D& { return d.layer_norm(std::move(path)); },
          py::arg("path"), self_ref)
      .def(
          "scale", [](D& d, double factor) -> D& { return d.scale(factor); }, py::arg("factor"),
          self_ref, "x · factor.")
      .def(
          "scale",
          [](D& d, std::string path, double value, bool trainable, double offset) -> D& {
            return d.scale(std::move(path), value, trainable, offset);
          },
          py::arg("path"), py::arg("value"), py::arg("trainable") = true, py::arg("offset") = 0.0,
          self_ref, "(offset + s) · x, s a learned scalar at path (a buffer unless trainable).")
      .def(
          "head_weights",
          [](D& d, std::string path, std::int64_t heads, std::int64_t out, double gain) -> D& {
            return d.head_weights(std::move(path), heads, out, gain);
          },
          py::arg("path"), py::arg("heads"), py::arg("out"), py::arg("gain") = 1.414, self_ref)
      .def(
          "bias",
          [](D& d, std::string path, std::vector<std::int64_t> shape, double gain) -> D& {
            return d.bias(std::move(path), std::move(shape), gain);
          },
          py::arg("path"), py::arg("shape") = std::vector<std::int64_t>{}, py::arg("gain") = 0.0,
          self_ref)
      .def(
          "pow", [](D& d, double e) -> D& { return d.pow(e); }, py::arg("exponent"), self_ref)
      .def(
          "normalize", [](D& d, bool per_row) -> D& { return d.normalize(per_row); },
          py::arg("per_row") = true, self_ref)
      .def(
          "mlp",
          [](D& d, std::string path, const MlpOptions& o) -> D& {
            return d.mlp(std::move(path), o);
          },
          py::arg("path"), py::arg("options"), self_ref)
      .def(
          "only", [](D& d, int role) -> D& { return d.only(role); }, py::arg("role"), self_ref)
      .def(
          "apply",
          [](D& d, py::object op) -> D& {
            return d.apply(
                std::shared_ptr<const Operation>(std::make_shared<PythonOperation>(std::move(op))));
          },
          py::arg("operation"), self_ref,
          "An operation written in Python (infer(ctx, x) and forward(ctx, x); topos.nn.Operation).")
      .def_property_readonly(
          "operations", [](const D& d) { return d.operations().size(); },
          "How many operations it applies.");
}

void bind_builder(py::module_& m) {
  py::enum_<Activation>(m, "Activation", "An activation (a name works too: 'relu').")
      .value("none", Activation::none)
      .value("relu", Activation::relu)
      .value("sigmoid", Activation::sigmoid)
      .value("tanh", Activation::tanh)
      .value("elu", Activation::elu)
      .value("leaky_relu", Activation::leaky_relu)
      .value("gelu", Activation::gelu)
      .value("selu", Activation::selu);
  m.attr("Update") = m.attr("Activation");  // deprecated: the earlier name
  py::enum_<Aggr>(m, "Aggr")
      .value("sum", Aggr::sum)
      .value("mean", Aggr::mean)
      .value("max", Aggr::max);
  py::enum_<AttentionNorm>(m, "AttentionNorm")
      .value("softmax", AttentionNorm::softmax)
      .value("row_sum", AttentionNorm::row_sum)
      .value("none", AttentionNorm::none);

  py::class_<MlpOptions>(m, "MlpOptions", "nn::Mlp's options: Linear layers with activations.")
      .def(py::init([](std::int64_t in, std::int64_t hidden, std::int64_t out, int layers,
                       const py::object& activation, bool final_activation, bool layer_norm) {
             return MlpOptions(in, hidden, out)
                 .layers(layers)
                 .activation(activation_arg(activation, "MlpOptions(activation)"))
                 .final_activation(final_activation)
                 .layer_norm(layer_norm);
           }),
           py::arg("in_channels"), py::arg("hidden"), py::arg("out"), py::kw_only(),
           py::arg("layers") = 2, py::arg("activation") = Activation::relu,
           py::arg("final_activation") = true, py::arg("layer_norm") = true);

  py::class_<ops::Term> term(m, "Term", "A term: a cochain and the operations applied to it.");
  bind_chain(term);
  term.def(
          "attend",
          [](ops::Term& t, std::string op, std::string param, const py::object& activation,
             AttentionNorm norm, double slope, std::optional<std::vector<std::int64_t>> shape,
             double gain, const py::object& keys, const py::object& queries, bool source_only,
             std::int64_t heads, bool concat, double dropout, bool transposed,
             const py::object& key_weights) -> ops::Term& {
            AttendOptions o(std::move(param));
            o.activation(activation_arg(activation, "attend(activation)"))
                .norm(norm)
                .negative_slope(slope)
                .gain(gain)
                .source_only(source_only)
                .heads(heads)
                .concat(concat)
                .dropout(dropout)
                .transposed(transposed);
            if (shape) o.shape(*shape);
            if (!keys.is_none()) o.keys(key_arg(keys, "attend(keys)"));
            if (!queries.is_none()) o.queries(key_arg(queries, "attend(queries)"));
            if (!key_weights.is_none())
              o.key_weights(key_weights_arg(key_weights, "attend(key_weights)"));
            return t.attend(std::move(op), std::move(o));
          },
          py::arg("op"), py::arg("param"), py::arg("activation") = Activation::elu,
          py::arg("norm") = AttentionNorm::none, py::arg("negative_slope") = 0.2, py::kw_only(),
          py::arg("shape") = py::none(), py::arg("gain") = 1.414, py::arg("keys") = py::none(),
          py::arg("queries") = py::none(), py::arg("source_only") = false, py::arg("heads") = 1,
          py::arg("concat") = true, py::arg("dropout") = 0.0, py::arg("transposed") = false,
          py::arg("key_weights") = py::none(), self_ref,
          "Messages over A weighted by attention (AttendOptions' fields as keywords; key_weights: "
          "(path, channels per head[, gain]), keys = keys · K_h folded into the scores).")
      .def(
          "powers",
          [](ops::Term& t, std::vector<std::pair<std::string, int>> filters, bool row_norm,
             int norm_from) -> ops::Term& {
            return t.powers(std::move(filters), row_norm, norm_from);
          },
          py::arg("filters"), py::arg("row_norm") = false, py::arg("norm_from") = 1, self_ref,
          "[y, A₁y..A₁^K₁y, ...] from [(operator, K), ...].")
      .def_property_readonly("source", [](const ops::Term& t) { return key_out(t.source); })
      .def("__repr__", [](const ops::Term& t) {
        return "<topos.nn.Term from " + t.source.str() + ", " +
               std::to_string(t.operations().size()) + " operations>";
      });
  m.def(
      "from_", [](int rank, std::string state) { return ops::from(rank, std::move(state)); },
      py::arg("rank"), py::arg("state") = "",
      "A term starting at cochain (rank, state): C++'s from (a keyword in Python).");

  py::class_<OperatorStep> step(m, "OperatorStep",
                                "A step: its terms, how they are mixed, the operations after.");
  bind_chain(step);
  step.def(
          "sum",
          [](OperatorStep& s, const py::args& t) -> OperatorStep& {
            return s.sum(terms_arg(t, "sum"));
          },
          self_ref, "The terms summed.")
      .def(
          "mean",
          [](OperatorStep& s, const py::args& t) -> OperatorStep& {
            s.sum(terms_arg(t, "mean"));
            s.mix = OperatorStep::Mix::mean;
            return s;
          },
          self_ref, "The terms averaged.")
      .def(
          "concat",
          [](OperatorStep& s, const py::args& t) -> OperatorStep& {
            return s.concat(terms_arg(t, "concat"));
          },
          self_ref, "The terms side by side.")
      .def(
          "filter",
          [](OperatorStep& s, std::string path, std::int64_t out,
             const py::args& t) -> OperatorStep& {
            s.sum(terms_arg(t, "filter"));
            s.mix = OperatorStep::Mix::filter;
            s.filter_path = std::move(path);
            s.filter_out = out;
            return s;
          },
          py::arg("path"), py::arg("out"), self_ref,
          "Σ_k T_k · W[:, :, k] over every term, W (in × out × terms) at path.")
      .def(
          "named",
          [](OperatorStep& s, std::string n) -> OperatorStep& { return s.named(std::move(n)); },
          py::arg("name"), self_ref)
      .def(
          "when_nonempty",
          [](OperatorStep& s, int r) -> OperatorStep& { return s.when_nonempty(r); },
          py::arg("rank"), self_ref)
      .def_property_readonly("target", [](const OperatorStep& s) { return key_out(s.target); })
      .def_property_readonly("name", [](const OperatorStep& s) { return s.name; });
  m.def(
      "into", [](int rank, std::string state) { return ops::into(rank, std::move(state)); },
      py::arg("rank"), py::arg("state") = "", "A step writing cochain (rank, state).");

  py::class_<OperatorSchedule>(m, "OperatorSchedule",
                               "Inputs, operators, steps and outputs; OperatorNetwork runs it.")
      .def(py::init<>())
      .def("input", &OperatorSchedule::input, py::arg("name"), py::arg("rank"), py::arg("channels"),
           py::arg("state") = "", self_ref)
      .def("operator_input", &OperatorSchedule::operator_input, py::arg("name"),
           py::arg("source_rank"), py::arg("target_rank"), self_ref)
      .def("optional_operator", &OperatorSchedule::optional_operator, py::arg("name"),
           py::arg("source_rank"), py::arg("target_rank"), self_ref)
      .def("step", &OperatorSchedule::step, py::arg("step"), self_ref)
      .def("parallel", &OperatorSchedule::parallel, py::arg("steps"), self_ref)
      .def("layer", &OperatorSchedule::layer, py::arg("name"), self_ref)
      .def("output", &OperatorSchedule::output, py::arg("name"), py::arg("rank"),
           py::arg("state") = "", self_ref)
      .def("parameter", &OperatorSchedule::parameter, py::arg("path"), py::arg("shape"),
           py::arg("gain") = 1.414, self_ref)
      .def_property_readonly(
          "inputs",
          [](const OperatorSchedule& s) {
            py::dict d;
            for (const auto& p : s.inputs())
              d[py::str(p.name)] = py::make_tuple(p.key.rank, p.key.state, p.channels);
            return d;
          },
          "name -> (rank, state, channels)")
      .def_property_readonly(
          "outputs",
          [](const OperatorSchedule& s) {
            py::dict d;
            for (const auto& p : s.outputs()) d[py::str(p.name)] = key_out(p.key);
            return d;
          },
          "name -> (rank, state)")
      .def_property_readonly("operators", &OperatorSchedule::operators,
                             "name -> (source rank, target rank)")
      .def("str", &OperatorSchedule::str)
      .def("__str__", &OperatorSchedule::str);
}

// ----- operations' interface -----------------------------------------------------------------

void bind_operation_api(py::module_& m) {
  py::class_<TermShape>(m, "TermShape", "A term's value while the network is built.")
      .def(py::init([](int rank, std::int64_t channels) {
             return TermShape{rank, channels};
           }),
           py::arg("rank"), py::arg("channels"))
      .def_readwrite("rank", &TermShape::rank)
      .def_readwrite("channels", &TermShape::channels)
      .def("__eq__",
           [](const TermShape& a, const TermShape& b) {
             return a.rank == b.rank && a.channels == b.channels;
           })
      .def("__repr__", [](const TermShape& s) {
        return "TermShape(rank=" + std::to_string(s.rank) +
               ", channels=" + std::to_string(s.channels) + ")";
      });

  py::class_<ParameterInit>(m, "ParameterInit", "How a new parameter is filled.")
      .def_static("glorot", &ParameterInit::glorot, py::arg("gain") = 1.414)
      .def_static("linear_weight", &ParameterInit::linear_weight)
      .def_static("linear_bias", &ParameterInit::linear_bias, py::arg("fan_in"))
      .def_static("uniform", &ParameterInit::uniform, py::arg("bound"))
      .def_static("zeros", &ParameterInit::zeros)
      .def_static("constant", &ParameterInit::constant, py::arg("value"));

  py::class_<OperationTraits>(m, "OperationTraits",
                              "What an operation promises, for the network's fast paths.")
      .def(py::init([](bool row_wise, bool reads_cochains, std::vector<std::string> operators,
                       const py::object& activation, double negative_slope, std::string identity,
                       std::string right_factor) {
             OperationTraits t;
             t.row_wise = row_wise;
             t.reads_cochains = reads_cochains;
             t.operators = std::move(operators);
             if (!activation.is_none())
               t.activation = activation_arg(activation, "OperationTraits(activation)");
             t.negative_slope = negative_slope;
             t.identity = std::move(identity);
             t.right_factor = std::move(right_factor);
             return t;
           }),
           py::kw_only(), py::arg("row_wise") = false, py::arg("reads_cochains") = true,
           py::arg("operators") = std::vector<std::string>{}, py::arg("activation") = py::none(),
           py::arg("negative_slope") = 0.01, py::arg("identity") = "", py::arg("right_factor") = "")
      .def_readwrite("row_wise", &OperationTraits::row_wise)
      .def_readwrite("reads_cochains", &OperationTraits::reads_cochains)
      .def_readwrite("operators", &OperationTraits::operators)
      .def_readwrite("negative_slope", &OperationTraits::negative_slope)
      .def_readwrite("identity", &OperationTraits::identity)
      .def_readwrite("right_factor", &OperationTraits::right_factor);

  py::class_<BuildRef, std::shared_ptr<BuildRef>>(
      m, "BuildContext", "What infer sees: the step, its operators and cochains, new parameters.")
      .def_property_readonly("where", [](const BuildRef& r) { return r.get().where(); })
      .def_property_readonly("target", [](const BuildRef& r) { return key_out(r.get().target()); })
      .def(
          "fail", [](const BuildRef& r, const std::string& why) { r.get().fail(why); },
          py::arg("why"), "Raises a ScheduleError naming the step.")
      .def(
          "operator_ranks",
          [](const BuildRef& r, const std::string& n) { return r.get().operator_ranks(n); },
          py::arg("name"), "(source rank, target rank) of a declared operator.")
      .def(
          "operator_from",
          [](const BuildRef& r, const std::string& n, int rank, bool transposed) {
            return r.get().operator_from(n, rank, transposed);
          },
          py::arg("name"), py::arg("rank"), py::arg("transposed") = false)
      .def(
          "cochain_width",
          [](const BuildRef& r, const py::object& key) {
            return r.get().cochain_width(key_arg(key, "cochain_width(key)"));
          },
          py::arg("key"), "The width of a cochain, rank or (rank, state), as the step reads it.")
      .def(
          "parameter",
          [](const BuildRef& r, const std::string& path, const std::vector<std::int64_t>& shape,
             const ParameterInit& init) { r.get().parameter(path, shape, init); },
          py::arg("path"), py::arg("shape"), py::arg("init") = ParameterInit::glorot(),
          "A parameter at a dotted path (shared when the path recurs).")
      .def(
          "buffer",
          [](const BuildRef& r, const std::string& path, const std::vector<std::int64_t>& shape,
             double value) { r.get().buffer(path, shape, value); },
          py::arg("path"), py::arg("shape"), py::arg("value") = 0.0,
          "A buffer at a dotted path: saved in the state_dict, not trained.");

  py::class_<RunRef, std::shared_ptr<RunRef>>(
      m, "RunContext", "What forward sees: operators, parameters, cochains before the step.")
      .def_property_readonly("where", [](const RunRef& r) { return r.get().where(); })
      .def_property_readonly("target", [](const RunRef& r) { return key_out(r.get().target()); })
      .def(
          "fail", [](const RunRef& r, const std::string& why) { r.get().fail(why); },
          py::arg("why"))
      .def(
          "op",
          [](const RunRef& r, const std::string& n) { return operator_out(r.get().op(n), n); },
          py::arg("name"), "A given operator as a torch sparse COO tensor.")
      .def(
          "op_transposed",
          [](const RunRef& r, const std::string& n) {
            return operator_out(r.get().op_transposed(n), n + "ᵀ");
          },
          py::arg("name"))
      .def(
          "parameter", [](const RunRef& r, const std::string& p) { return r.get().parameter(p); },
          py::arg("path"), "A parameter or buffer: the module's own tensor.")
      .def(
          "cochain",
          [](const RunRef& r, const py::object& key) {
            return r.get().cochain(key_arg(key, "cochain(key)"));
          },
          py::arg("key"))
      .def("is_training", [](const RunRef& r) { return r.get().is_training(); })
      .def(
          "scratch",
          [](const RunRef& r, const std::string& key) -> py::object {
            const auto& t = r.get().scratch(key);
            return t.defined() ? py::cast(t) : py::none();
          },
          py::arg("key"), "A tensor kept for one run of the schedule (None until set).")
      .def(
          "set_scratch",
          [](const RunRef& r, const std::string& key, const at::Tensor& t) {
            r.get().scratch(key) = t;
          },
          py::arg("key"), py::arg("value"));
}

// ----- the network ---------------------------------------------------------------------------

/// A ScheduleError's advice in Python's spelling: its messages say what to write in C++
/// ("x.to(torch::kFloat32), or convert the network with net->to(torch::kFloat64)").
template <class F>
auto python_spelling(F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const ScheduleError& e) {
    std::string m = e.what();
    for (const auto& [cpp, py] :
         {std::pair<std::string, std::string>{"torch::kFloat32", "torch.float32"},
          {"torch::kFloat64", "torch.float64"},
          {"torch::kHalf", "torch.float16"},
          {"torch::kBFloat16", "torch.bfloat16"},
          {"torch::Device(", "torch.device("},
          {"net->", "net."}})
      for (auto at = m.find(cpp); at != std::string::npos; at = m.find(cpp, at + py.size()))
        m.replace(at, cpp.size(), py);
    throw ScheduleError(m);
  }
}

/// The dtype the network computes in: its first floating parameter's (float32 without any).
at::ScalarType network_dtype(OperatorNetworkImpl& net) {
  for (const auto& p : net.parameters())
    if (p.is_floating_point()) return p.scalar_type();
  return at::typeMetaToScalarType(at::get_default_dtype());
}

/// A forward's arguments from Python: inputs as dense tensors, operators converted to the
/// network's dtype, each with an error naming it.
std::pair<std::map<std::string, torch::Tensor>, std::map<std::string, SparseOperator>> network_args(
    OperatorNetworkImpl& net, const py::dict& inputs, const py::dict& operators) {
  std::map<std::string, torch::Tensor> x;
  for (const auto& [k, v] : inputs) {
    if (!py::isinstance<py::str>(k))
      throw py::type_error("inputs: keys are the inputs' names (str), got a " + type_name(k));
    const std::string name = k.cast<std::string>();
    if (!THPVariable_Check(v.ptr()))
      throw py::type_error("inputs['" + name + "']: expected a torch.Tensor, got a " +
                           type_name(v));
    const at::Tensor t = py::cast<at::Tensor>(v);
    if (t.layout() != at::kStrided)
      throw py::type_error("inputs['" + name + "']: expected a dense tensor (cells × " +
                           "channels), got a sparse one; pass x.to_dense()");
    x.emplace(name, t);
  }
  const at::ScalarType dtype = network_dtype(net);
  std::map<std::string, SparseOperator> a;
  for (const auto& [k, v] : operators) {
    if (!py::isinstance<py::str>(k))
      throw py::type_error("operators: keys are the operators' names (str), got a " + type_name(k));
    const std::string name = k.cast<std::string>();
    a.emplace(name, operator_arg(v, "operators['" + name + "']", dtype));
  }
  return {std::move(x), std::move(a)};
}

void bind_network(py::module_& m) {
  py::class_<SparseOperator>(m, "SparseOperator",
                             "An operator converted once (CSR with its transpose), for forwards "
                             "that reuse it.")
      .def(py::init([](const py::object& a, const py::object& dtype) {
             const at::ScalarType t = dtype.is_none()
                                          ? at::typeMetaToScalarType(at::get_default_dtype())
                                          : out_spec("coo", dtype, "SparseOperator(dtype)").dtype;
             return operator_arg(a, "SparseOperator(A)", t);
           }),
           py::arg("A"), py::arg("dtype") = py::none(),
           "From a torch sparse COO / CSR tensor or scipy.sparse (dtype: scipy's values).")
      .def_property_readonly("shape",
                             [](const SparseOperator& a) { return py::make_tuple(a.rows, a.cols); })
      .def_property_readonly("nnz", &SparseOperator::nnz)
      .def(
          "to_torch", [](const SparseOperator& a) { return operator_out(a, "to_torch"); },
          "As a torch sparse COO tensor.");

  using Net = OperatorNetworkImpl;
  py::class_<Net, std::shared_ptr<Net>>(m, "_Network",
                                        "The C++ OperatorNetwork (topos.nn.OperatorNetwork wraps "
                                        "it in a torch.nn.Module).")
      .def(py::init([](const OperatorSchedule& s) {
             return python_spelling([&] { return std::make_shared<Net>(s); });
           }),
           py::arg("schedule"))
      .def(
          "tensors",
          [](Net& net) {
            py::list out;
            for (const auto& p : net.named_parameters(true))
              out.append(py::make_tuple(p.key(), p.value(), false));
            for (const auto& b : net.named_buffers(true))
              out.append(py::make_tuple(b.key(), b.value(), true));
            return out;
          },
          "(path, tensor, is_buffer) for every parameter and buffer: the network's own tensors.")
      .def(
          "forward",
          [](Net& net, const py::dict& inputs, const py::dict& operators, bool training) {
            const auto args = network_args(net, inputs, operators);
            const auto& x = args.first;
            const auto& a = args.second;
            std::map<std::string, torch::Tensor> y;
            {
              py::gil_scoped_release release;  // a Python operation takes it back
              net.train(training);
              y = python_spelling([&] { return net.forward(x, a); });
            }
            return y;
          },
          py::arg("inputs"), py::arg("operators"), py::arg("training"))
      .def(
          "plan",
          [](Net& net, const py::dict& inputs, const py::dict& operators) {
            const auto args = network_args(net, inputs, operators);
            const auto& x = args.first;
            const auto& a = args.second;
            const auto plan = python_spelling([&] { return net.plan(x, a); });
            py::list steps;
            for (const auto& group : plan.groups)
              for (const auto& p : group) {
                if (!p.live) continue;
                py::list terms, lines;
                for (const auto& t : p.terms) terms.append(t.term->source.str());
                for (const auto& l : p.lines)
                  lines.append(py::dict(py::arg("depth") = l.depth, py::arg("what") = l.what,
                                        py::arg("flops") = l.flops,
                                        py::arg("fused_with_next") = l.fused_with_next,
                                        py::arg("rows") = l.rows, py::arg("channels") = l.channels,
                                        py::arg("terms") = l.terms));
                steps.append(py::dict(
                    py::arg("name") = p.step->name, py::arg("target") = p.step->target.str(),
                    py::arg("group") = p.group, py::arg("route") = route_name(p.route),
                    py::arg("terms") = terms, py::arg("compact_readers") = p.compact_readers,
                    py::arg("lines") = lines));
              }
            return py::dict(py::arg("text") = plan.str(), py::arg("steps") = steps,
                            py::arg("total_flops") = plan.total_flops,
                            py::arg("total_values") = plan.total_values,
                            py::arg("value_bytes") = plan.value_bytes,
                            py::arg("fast_paths") = plan.fast_paths.str());
          },
          py::arg("inputs"), py::arg("operators"),
          "The plan forward(inputs, operators) runs, as a dict (topos.nn.Plan wraps it).")
      .def("set_fast_paths", &Net::set_fast_paths, py::arg("on"))
      .def(
          "set_fast_path",
          [](Net& net, const std::string& name, bool on) { net.fast_paths().set(name, on); },
          py::arg("name"), py::arg("on"),
          "One fast path on or off by name (FastPaths::names(); another is a ValueError).")
      .def(
          "fast_paths",
          [](const Net& net) {
            py::dict d;
            for (const auto& name : FastPaths::names())
              d[py::str(name)] = net.fast_paths().get(name);
            return d;
          },
          "Each fast path's name and whether it is on, in FastPaths::names()'s order.")
      .def_property(
          "step_threads", [](const Net& net) { return net.step_threads(); },
          [](Net& net, int n) { net.step_threads(n); },
          "Threads a parallel group's steps share outside training (OperatorNetworkImpl::"
          "step_threads; 1: the calling thread alone).")
      .def_property_readonly(
          "split_groups", [](const Net& net) { return net.split_groups(); },
          "How many parallel groups forwards have run on more than one thread "
          "(OperatorNetworkImpl::split_groups).")
      .def_property_readonly(
          "split_steps", [](const Net& net) { return net.split_steps(); },
          "How many steps forwards have run with their terms at once "
          "(OperatorNetworkImpl::split_steps).")
      .def_property_readonly("schedule", &Net::schedule, py::return_value_policy::copy);
}

}  // namespace

void bind_schedule(py::module_& parent) {
  schedule_error_type =
      py::register_local_exception<ScheduleError>(parent, "ScheduleError", PyExc_ValueError).ptr();
  py::handle(schedule_error_type).attr("__doc__") =
      "A schedule that cannot be built or run; the message names the step or the argument.";
  py::module_ m = parent.def_submodule(
      "nn", "The operator schedule and its network (the package topos.nn wraps them).");
  m.attr("ScheduleError") = py::handle(schedule_error_type);
  bind_builder(m);
  bind_operation_api(m);
  bind_network(m);
  // The C++ programs' allocator settings (topos/nn/cpu.hpp), for a Python process that runs
  // many large forwards: glibc gives large freed blocks back and faults them in again.
  m.def("use_caching_cpu_allocator", &use_caching_cpu_allocator,
        py::arg("max_cached_bytes") = std::size_t(1) << 30,
        "Allocates CPU tensors (torch's too) through a size-class cache: freed blocks of 1 MB or "
        "more are kept (at most max_cached_bytes) and reused, as bench_zoo and the hopnet trainer "
        "do. Tensors allocated before keep their allocator.");
  m.def(
      "set_cpu_gemm",
      [](const std::string& library) { set_cpu_gemm(cpu_gemm_from_string(library)); },
      py::arg("library"),
      "The library of the float32 CPU products of topos's Linear layers (its MLPs, `linear`), "
      "process-wide: 'blas' (OpenBLAS through LibTorch, the default), 'onednn' (oneDNN's sgemm: "
      "its AVX-512 kernels where OpenBLAS does not know the CPU) or 'topos' (topos's dense "
      "kernel). They "
      "differ in float32 summation order only.");
  m.def(
      "get_cpu_gemm", [] { return std::string(to_string(get_cpu_gemm())); },
      "The library set_cpu_gemm chose: 'blas', 'onednn' or 'topos'.");
  m.def(
      "set_float32_matmul_precision",
      [](const std::string& precision) {
        set_float32_matmul_precision(matmul_precision_from_string(precision));
      },
      py::arg("precision"),
      "How topos multiplies float32 products, process-wide, as torch.set_float32_matmul_precision "
      "names it (torch's own setting does not reach topos's kernels): 'highest' (float32, the "
      "default) or 'medium' (bfloat16 inputs, float32 sums and outputs, on topos's AVX-512 BF16 "
      "or AMX kernels where the CPU has them; bfloat16_kernels() says which).");
  m.def(
      "get_float32_matmul_precision",
      [] { return std::string(to_string(get_float32_matmul_precision())); },
      "The precision set_float32_matmul_precision chose: 'highest' or 'medium'.");
  m.def(
      "bfloat16_kernels", [] { return std::string(bfloat16_kernels()); },
      "The kernels that run 'medium''s CPU products here: 'amx', 'avx512-bf16' or 'onednn' (a "
      "CPU without AVX-512 BF16: only Linear layers and MLPs multiply in bfloat16 there, through "
      "oneDNN; the schedule's other products stay float32).");
  m.def("cached_cpu_bytes", &cached_cpu_bytes, "Bytes the CPU cache holds on its free lists.");
  m.def("release_cached_cpu_memory", &release_cached_cpu_memory,
        "Gives the CPU cache's free blocks back to the system.");
}

}  // namespace topos::python
