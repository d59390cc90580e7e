// python/src/module.cpp
// The extension topos._C: the four domains with TopoNetX's names and conventions, their
// operators (as torch sparse tensors, or scipy.sparse on request), the graph liftings, TopoNetX's
// normalisations, the exceptions, (hopnet.cpp) HOPNet and (schedule.cpp) the operator schedule.
// Operators are computed with the GIL released. python/topos/ is the package around it.
#include "convert.hpp"

#include "topos/core/domain_lifting.hpp"
#include "topos/core/normalization.hpp"
#include "topos/data/json.hpp"

#include <ATen/ops/_sparse_coo_tensor_unsafe.h>
#include <ATen/ops/_sparse_csr_tensor_unsafe.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/zeros.h>
#include <c10/core/DefaultDtype.h>
#include <c10/util/Exception.h>
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <cstring>
#include <optional>
#include <sstream>

namespace topos::python {

void bind_hopnet(py::module_& m);     // hopnet.cpp
void bind_schedule(py::module_& m);   // schedule.cpp
void bind_zoo(py::module_& m);        // zoo.cpp
void bind_topobench(py::module_& m);  // topobench.cpp

// ----- conversions (convert.hpp) ------------------------------------------------------------

std::string type_name(const py::handle& obj) {
  const py::handle t = py::type::handle_of(obj);
  const std::string mod = py::str(t.attr("__module__")), name = py::str(t.attr("__qualname__"));
  return mod == "builtins" ? name : mod + "." + name;
}

OutSpec out_spec(const std::string& format, const py::object& dtype, const std::string& where) {
  OutSpec o;
  if (format == "coo") {
    o.format = Format::coo;
  } else if (format == "csr") {
    o.format = Format::csr;
  } else if (format == "dense") {
    o.format = Format::dense;
  } else if (format == "scipy") {
    o.format = Format::scipy;
  } else {
    throw py::value_error(where + ": format '" + format +
                          "' is not one of 'coo' (torch sparse COO), 'csr' (torch sparse CSR), "
                          "'dense' (torch) or 'scipy' (scipy.sparse.csr_matrix)");
  }
  if (dtype.is_none()) {
    o.dtype =
        o.format == Format::scipy ? at::kDouble : at::typeMetaToScalarType(at::get_default_dtype());
  } else if (THPDtype_Check(dtype.ptr())) {
    o.dtype = reinterpret_cast<THPDtype*>(dtype.ptr())->scalar_type;
    if (!at::isFloatingType(o.dtype))
      throw py::type_error(where + ": dtype must be a floating dtype (torch.float32, " +
                           "torch.float64, ...), got " + std::string(py::str(dtype)));
  } else {
    throw py::type_error(where + ": dtype must be a torch.dtype such as torch.float32, got " +
                         type_name(dtype));
  }
  return o;
}

namespace {

py::object to_numpy(const at::Tensor& t) {
  return py::cast(t).attr("numpy")();
}

// A compressed copy when `m` is not (every operator is; the check is free).
const SparseMatrix& compressed(const SparseMatrix& m, std::optional<SparseMatrix>& keep) {
  if (m.isCompressed()) return m;
  keep.emplace(m);
  keep->makeCompressed();
  return *keep;
}

}  // namespace

py::object emit(const SparseMatrix& matrix, const OutSpec& out) {
  std::optional<SparseMatrix> keep;
  const SparseMatrix& m = compressed(matrix, keep);
  const Index rows = m.rows(), cols = m.cols(), nnz = m.nonZeros();
  const auto values = [&] {
    at::Tensor v = at::empty({nnz}, at::kDouble);
    if (nnz) std::memcpy(v.data_ptr<double>(), m.valuePtr(), sizeof(double) * nnz);
    return out.dtype == at::kDouble ? v : v.to(out.dtype);
  };
  const auto copy_index = [](const std::int64_t* p, Index n) {
    at::Tensor t = at::empty({n}, at::kLong);
    if (n) std::memcpy(t.data_ptr<std::int64_t>(), p, sizeof(std::int64_t) * n);
    return t;
  };
  switch (out.format) {
    case Format::coo: {
      // Row-major with sorted, unique columns per row: the COO order torch calls coalesced.
      at::Tensor idx = at::empty({2, nnz}, at::kLong);
      std::int64_t* r = idx.data_ptr<std::int64_t>();
      if (nnz) std::memcpy(r + nnz, m.innerIndexPtr(), sizeof(std::int64_t) * nnz);
      for (Index i = 0; i < rows; ++i)
        for (Index k = m.outerIndexPtr()[i]; k < m.outerIndexPtr()[i + 1]; ++k) r[k] = i;
      at::Tensor v = values();
      at::Tensor t = at::_sparse_coo_tensor_unsafe(idx, v, {rows, cols}, v.options());
      t._coalesced_(true);
      return py::cast(t);
    }
    case Format::csr: {
      at::Tensor v = values();
      return py::cast(at::_sparse_csr_tensor_unsafe(
          copy_index(m.outerIndexPtr(), rows + 1), copy_index(m.innerIndexPtr(), nnz), v,
          {rows, cols}, v.options().layout(at::kSparseCsr)));
    }
    case Format::dense: {
      at::Tensor d = at::zeros({rows, cols}, at::kDouble);
      double* p = d.data_ptr<double>();
      for (Index i = 0; i < rows; ++i)
        for (Index k = m.outerIndexPtr()[i]; k < m.outerIndexPtr()[i + 1]; ++k)
          p[i * cols + m.innerIndexPtr()[k]] = m.valuePtr()[k];
      return py::cast(out.dtype == at::kDouble ? d : d.to(out.dtype));
    }
    case Format::scipy: {
      // The arrays are the tensors' memory (numpy() shares it); scipy keeps them alive.
      const py::object sp = py::module_::import("scipy.sparse");
      return sp.attr("csr_matrix")(
          py::make_tuple(to_numpy(values()), to_numpy(copy_index(m.innerIndexPtr(), nnz)),
                         to_numpy(copy_index(m.outerIndexPtr(), rows + 1))),
          py::arg("shape") = py::make_tuple(rows, cols));
    }
  }
  throw std::logic_error("emit: unknown format");
}

namespace {

bool is_tensor(const py::handle& obj) {
  return THPVariable_Check(obj.ptr());
}

// An object with the array interface (numpy) as a torch tensor (shares its memory).
std::optional<at::Tensor> as_tensor(const py::handle& obj) {
  if (is_tensor(obj)) return py::cast<at::Tensor>(obj);
  if (py::hasattr(obj, "__array_interface__"))
    return py::cast<at::Tensor>(py::module_::import("torch").attr("as_tensor")(obj));
  return std::nullopt;
}

SparseMatrix from_triplets(Index rows, Index cols, const std::int64_t* r, const std::int64_t* c,
                           const double* v, Index nnz, const std::string& arg) {
  std::vector<Eigen::Triplet<double, std::int64_t>> t;
  t.reserve(static_cast<std::size_t>(nnz));
  for (Index k = 0; k < nnz; ++k) {
    if (r[k] < 0 || r[k] >= rows || c[k] < 0 || c[k] >= cols)
      throw py::value_error(arg + ": entry (" + std::to_string(r[k]) + ", " + std::to_string(c[k]) +
                            ") is outside the " + std::to_string(rows) + " x " +
                            std::to_string(cols) + " shape");
    if (v[k] != 0.0) t.emplace_back(r[k], c[k], v[k]);
  }
  SparseMatrix m(rows, cols);
  m.setFromTriplets(t.begin(), t.end());
  return sparse::pruned(m);  // duplicates that cancel leave no stored zero
}

at::Tensor real_values(const at::Tensor& v, const std::string& arg) {
  if (at::isComplexType(v.scalar_type()))
    throw py::type_error(arg + ": complex values are not supported (topos operators are real)");
  return v.to(at::kCPU, at::kDouble).contiguous();
}

SparseMatrix sparse_arg_unchecked(const py::handle& obj, const std::string& arg) {
  if (is_tensor(obj)) {
    const at::Tensor t = py::cast<at::Tensor>(obj);
    if (t.layout() == at::kStrided)
      throw py::type_error(arg + ": expected a sparse matrix, got a dense torch.Tensor of shape " +
                           c10::str(t.sizes()) + "; pass x.to_sparse() (COO) or " +
                           "x.to_sparse_csr()");
    if (t.dim() != 2)
      throw py::value_error(arg + ": expected a 2-D sparse matrix, got " + std::to_string(t.dim()) +
                            " dimensions");
    const Index rows = t.size(0), cols = t.size(1);
    if (t.layout() == at::kSparse) {
      const at::Tensor c = t.coalesce();
      const at::Tensor idx = c.indices().to(at::kCPU, at::kLong).contiguous();
      const at::Tensor v = real_values(c.values(), arg);
      if (v.dim() != 1)
        throw py::value_error(arg + ": a hybrid sparse tensor (dense values per entry) is not " +
                              "a matrix");
      const Index nnz = v.size(0);
      const std::int64_t* p = idx.data_ptr<std::int64_t>();
      return from_triplets(rows, cols, p, p + nnz, v.data_ptr<double>(), nnz, arg);
    }
    if (t.layout() == at::kSparseCsr) {
      const at::Tensor crow = t.crow_indices().to(at::kCPU, at::kLong).contiguous();
      const at::Tensor col = t.col_indices().to(at::kCPU, at::kLong).contiguous();
      const at::Tensor v = real_values(t.values(), arg);
      const Index nnz = v.size(0);
      std::vector<std::int64_t> r(static_cast<std::size_t>(nnz));
      const std::int64_t* cr = crow.data_ptr<std::int64_t>();
      for (Index i = 0; i < rows; ++i)
        for (Index k = cr[i]; k < cr[i + 1]; ++k) r[static_cast<std::size_t>(k)] = i;
      return from_triplets(rows, cols, r.data(), col.data_ptr<std::int64_t>(), v.data_ptr<double>(),
                           nnz, arg);
    }
    throw py::type_error(arg + ": torch layout " + c10::str(t.layout()) +
                         " is not supported; pass a sparse COO or CSR tensor");
  }
  const std::string type = type_name(obj);
  if (type.rfind("scipy.sparse", 0) == 0) {
    const py::object coo = obj.attr("tocoo")();
    const py::tuple shape = coo.attr("shape");
    if (shape.size() != 2)
      throw py::value_error(arg + ": expected a 2-D sparse matrix, got " + type);
    using I = py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>;
    using D = py::array_t<double, py::array::c_style | py::array::forcecast>;
    const py::object data = coo.attr("data");
    if (std::string(py::str(data.attr("dtype").attr("kind"))) == "c")
      throw py::type_error(arg + ": complex values are not supported (topos operators are real)");
    const I r = I::ensure(coo.attr("row")), c = I::ensure(coo.attr("col"));
    const D v = D::ensure(data);
    return from_triplets(shape[0].cast<Index>(), shape[1].cast<Index>(), r.data(), c.data(),
                         v.data(), static_cast<Index>(v.size()), arg);
  }
  if (py::hasattr(obj, "__array_interface__"))
    throw py::type_error(arg + ": expected a sparse matrix, got a dense " + type +
                         "; pass torch.as_tensor(x).to_sparse() or scipy.sparse.csr_matrix(x)");
  throw py::type_error(arg + ": expected a sparse matrix (torch sparse COO or CSR tensor, or " +
                       "scipy.sparse), got " + type);
}

}  // namespace

SparseMatrix sparse_arg(const py::handle& obj, const std::string& arg) {
  try {
    return sparse_arg_unchecked(obj, arg);
  } catch (const c10::Error& e) {  // torch's own checks (coalesce of indices out of range, ...)
    throw py::value_error(arg + ": " + e.what_without_backtrace());
  }
}

namespace {

Index node_id(const py::handle& h, const std::string& where) {
  if (PyBool_Check(h.ptr()) || !PyIndex_Check(h.ptr()))
    throw py::type_error(where + " must be an integer node id, got " + type_name(h));
  const Py_ssize_t v = PyNumber_AsSsize_t(h.ptr(), PyExc_OverflowError);
  if (v == -1 && PyErr_Occurred()) throw py::error_already_set();
  return static_cast<Index>(v);
}

void require_integer_tensor(const at::Tensor& t, const std::string& arg) {
  if (!at::isIntegralType(t.scalar_type(), /*includeBool=*/false))
    throw py::type_error(arg + ": node ids must be integers, got a tensor of dtype " +
                         std::string(c10::toString(t.scalar_type())));
}

std::vector<Index> tensor_rows_flat(const at::Tensor& t) {
  const at::Tensor l = t.to(at::kCPU, at::kLong).contiguous();
  const std::int64_t* p = l.data_ptr<std::int64_t>();
  return std::vector<Index>(p, p + l.numel());
}

bool is_string(const py::handle& obj) {
  return PyUnicode_Check(obj.ptr()) || PyBytes_Check(obj.ptr());
}

}  // namespace

std::vector<Index> cell_arg(const py::handle& obj, const std::string& arg) {
  if (auto t = as_tensor(obj)) {
    require_integer_tensor(*t, arg);
    if (t->dim() != 1)
      throw py::value_error(arg + ": expected one cell (a 1-D list of node ids), got a tensor " +
                            "of shape " + c10::str(t->sizes()));
    return tensor_rows_flat(*t);
  }
  if (is_string(obj) || !py::isinstance<py::iterable>(obj))
    throw py::type_error(arg + " must be a list of integer node ids, got " + type_name(obj));
  std::vector<Index> c;
  std::size_t i = 0;
  for (const py::handle v : obj) c.push_back(node_id(v, arg + "[" + std::to_string(i++) + "]"));
  return c;
}

Cells cells_arg(const py::handle& obj, const std::string& arg) {
  Cells cells;
  if (auto t = as_tensor(obj)) {
    require_integer_tensor(*t, arg);
    if (t->dim() != 2)
      throw py::value_error(arg + ": a tensor of cells must be 2-D (one cell per row), got " +
                            "shape " + c10::str(t->sizes()));
    const auto flat = tensor_rows_flat(*t);
    const auto w = static_cast<std::size_t>(t->size(1));
    for (std::size_t r = 0; r < static_cast<std::size_t>(t->size(0)); ++r)
      cells.emplace_back(flat.begin() + static_cast<std::ptrdiff_t>(r * w),
                         flat.begin() + static_cast<std::ptrdiff_t>((r + 1) * w));
    return cells;
  }
  if (is_string(obj) || !py::isinstance<py::iterable>(obj))
    throw py::type_error(arg + " must be a list of cells (lists of node ids), got " +
                         type_name(obj));
  std::size_t i = 0;
  for (const py::handle c : obj) {
    const std::string where = arg + "[" + std::to_string(i++) + "]";
    if (PyIndex_Check(c.ptr()) && !is_tensor(c))
      throw py::type_error(where + " is the single node " + std::string(py::str(c)) +
                           "; a cell is a list of node ids (write [" + std::string(py::str(c)) +
                           "])");
    cells.push_back(cell_arg(c, where));
  }
  return cells;
}

Edges edges_arg(const py::handle& obj, const std::string& arg) {
  Edges edges;
  if (auto t = as_tensor(obj)) {
    require_integer_tensor(*t, arg);
    if (t->dim() != 2 || t->size(0) != 2)
      throw py::value_error(arg + ": an edge tensor must have shape (2, E) (PyG's edge_index), " +
                            "got " + c10::str(t->sizes()));
    const auto flat = tensor_rows_flat(*t);
    const auto e = static_cast<std::size_t>(t->size(1));
    for (std::size_t k = 0; k < e; ++k) edges.push_back({flat[k], flat[e + k]});
    return edges;
  }
  for (const auto& c : cells_arg(obj, arg)) {
    if (c.size() != 2)
      throw py::value_error(arg + "[" + std::to_string(edges.size()) + "]: an edge has 2 nodes, " +
                            "got " + std::to_string(c.size()));
    edges.push_back({c[0], c[1]});
  }
  return edges;
}

Eigen::VectorXd vector_arg(const py::handle& obj, const std::string& arg, Index expected) {
  at::Tensor t;
  if (auto a = as_tensor(obj)) {
    t = *a;
  } else {
    if (is_string(obj) || !py::isinstance<py::iterable>(obj))
      throw py::type_error(arg + " must be a vector of numbers, got " + type_name(obj));
    t = py::cast<at::Tensor>(py::module_::import("torch").attr("tensor")(
        obj, py::arg("dtype") = py::module_::import("torch").attr("float64")));
  }
  if (t.dim() != 1)
    throw py::value_error(arg + ": expected a vector, got shape " + c10::str(t.sizes()));
  if (expected >= 0 && t.size(0) != expected)
    throw py::value_error(arg + ": expected " + std::to_string(expected) + " entries, got " +
                          std::to_string(t.size(0)));
  const at::Tensor d = real_values(t, arg);
  return Eigen::Map<const Eigen::VectorXd>(d.data_ptr<double>(), d.size(0));
}

Signed signed_arg(const py::handle& obj, const std::string& where) {
  if (!PyBool_Check(obj.ptr()))
    throw py::type_error(where + ": signed must be True or False, got " + type_name(obj) + " " +
                         std::string(py::str(obj)) +
                         " (an operator between two ranks is incidence_matrix(rank, to_rank) "
                         "of a CombinatorialComplex)");
  return obj.ptr() == Py_True ? Signed::yes : Signed::no;
}

// ----- the bindings ---------------------------------------------------------------------------

namespace {

// The keyword arguments every operator method ends with.
#define TOPOS_OUT_ARGS py::kw_only(), py::arg("format") = "coo", py::arg("dtype") = py::none()

// Runs `f` (returning a SparseMatrix) without the GIL and returns the result as `out` says.
template <class F>
py::object op(const OutSpec& out, F&& f) {
  SparseMatrix m;
  {
    py::gil_scoped_release release;
    SparseMatrix r = f();
    m.swap(r);  // Eigen 3.4's SparseMatrix has no move assignment; swap is O(1)
  }
  return emit(m, out);
}

template <class T>
std::string shape_repr(const char* name, const T& d) {
  std::ostringstream s;
  s << name << "(shape=(";
  const auto sh = d.shape();
  for (std::size_t i = 0; i < sh.size(); ++i) s << (i ? ", " : "") << sh[i];
  s << (sh.size() == 1 ? ",))" : "))");
  return s.str();
}

py::tuple shape_tuple(const std::vector<Index>& s) {
  return py::tuple(py::cast(s));
}

at::Tensor vector_tensor(const Eigen::VectorXd& v) {
  at::Tensor t = at::empty({v.size()}, at::kDouble);
  std::copy(v.data(), v.data() + v.size(), t.data_ptr<double>());
  return t;
}

Index num_nodes_of(const Cells& cells, const py::object& num_nodes) {
  if (!num_nodes.is_none()) return node_id(num_nodes, "num_nodes");
  Index n = 0;
  for (const auto& c : cells)
    for (Index v : c) n = std::max(n, v + 1);
  return n;
}

// A method name(rank, signed=default, *, format, dtype) returning f(complex, rank, sign).
template <class C, class F>
void def_signed_operator(py::class_<C>& cls, const std::string& cls_name, const char* name,
                         bool default_sign, F f, const char* doc) {
  const std::string where = cls_name + "." + name;
  cls.def(
      name,
      [where, f](const C& c, int rank, const py::object& sign, const std::string& format,
                 const py::object& dtype) {
        const Signed s = signed_arg(sign, where);
        return op(out_spec(format, dtype, where), [&] { return f(c, rank, s); });
      },
      py::arg("rank"), py::arg("signed") = default_sign, TOPOS_OUT_ARGS, doc);
}

// A method name(rank, other_rank, *, format, dtype) returning f(domain, rank, other_rank): the
// operators between two ranks of the combinatorial complex and the hypergraph.
template <class C, class F, class... Extra>
void def_rank_pair_operator(py::class_<C>& cls, const std::string& cls_name, const char* name, F f,
                            const char* doc, const Extra&... ranks) {
  const std::string where = cls_name + "." + name;
  cls.def(
      name,
      [where, f](const C& c, int rank, int other, const std::string& format,
                 const py::object& dtype) {
        return op(out_spec(format, dtype, where), [&] { return f(c, rank, other); });
      },
      ranks..., TOPOS_OUT_ARGS, doc);
}

// The oriented operators of the simplicial and cell complexes (TopoNetX's methods and defaults)
// and their common queries.
template <class C>
void def_oriented_operators(py::class_<C>& cls, const std::string& name) {
  using S = Signed;
  const auto on = [](S s) { return s == S::yes; };
  def_signed_operator(
      cls, name, "incidence_matrix", true,
      [](const C& c, int r, S s) { return c.incidence_matrix(r, s); },
      "B_rank (n_{rank-1} x n_rank), TopoNetX's incidence_matrix(rank, signed)");
  def_signed_operator(
      cls, name, "coincidence_matrix", true,
      [](const C& c, int r, S s) { return c.coincidence_matrix(r, s); }, "B_rank^T");
  def_signed_operator(
      cls, name, "up_laplacian_matrix", true,
      [on](const C& c, int r, S s) { return c.up_laplacian_matrix(r, on(s)); },
      "B_{rank+1} B_{rank+1}^T (|.| entrywise when unsigned)");
  def_signed_operator(
      cls, name, "down_laplacian_matrix", true,
      [on](const C& c, int r, S s) { return c.down_laplacian_matrix(r, on(s)); },
      "B_rank^T B_rank (|.| entrywise when unsigned)");
  def_signed_operator(
      cls, name, "hodge_laplacian_matrix", true,
      [on](const C& c, int r, S s) { return c.hodge_laplacian_matrix(r, on(s)); },
      "down + up Laplacian (terms of missing ranks omitted)");
  def_signed_operator(
      cls, name, "adjacency_matrix", false,
      [](const C& c, int r, S s) { return c.adjacency_matrix(r, s); },
      "cells of `rank` sharing a coface (TopoNetX's adjacency_matrix; unsigned by default)");
  def_signed_operator(
      cls, name, "coadjacency_matrix", false,
      [](const C& c, int r, S s) { return c.coadjacency_matrix(r, s); },
      "cells of `rank` sharing a face (TopoNetX's coadjacency_matrix; unsigned by default)");
  const std::string normalized = name + ".normalized_laplacian_matrix";
  cls.def(
         "normalized_laplacian_matrix",
         [normalized](const C& c, int rank, const std::string& format, const py::object& dtype) {
           return op(out_spec(format, dtype, normalized),
                     [&] { return c.normalized_laplacian_matrix(rank); });
         },
         py::arg("rank"), TOPOS_OUT_ARGS, "D^-1/2 L D^-1/2 of the signed Hodge Laplacian")
      .def_property_readonly("shape", [](const C& c) { return shape_tuple(c.shape()); })
      .def_property_readonly("dim", &C::dim)
      .def_property_readonly("num_nodes", &C::num_nodes)
      .def("__len__", &C::num_nodes)
      .def("num_cells", &C::num_cells, py::arg("rank"))
      .def("skeleton", &C::skeleton, py::arg("rank"),
           "the cells of a rank as node lists, in id order")
      .def("euler_characteristic", &C::euler_characteristic)
      .def("__repr__", [name](const C& c) { return shape_repr(name.c_str(), c); });
}

void bind_simplicial(py::module_& m) {
  using SC = SimplicialComplex;
  py::class_<SC> cls(m, "SimplicialComplex",
                     "A simplicial complex on nodes 0..n-1 (topos/core/simplicial_complex.hpp): "
                     "closed under faces, TopoNetX's cell order and signs.");
  cls.def(py::init([](const py::object& simplices, const py::object& num_nodes) {
            const Cells cells = cells_arg(simplices, "SimplicialComplex(simplices)");
            const Index n = num_nodes.is_none() ? -1 : node_id(num_nodes, "num_nodes");
            py::gil_scoped_release release;
            return SC::from_simplices(cells, n);
          }),
          py::arg("simplices") = py::list(), py::arg("num_nodes") = py::none(),
          "the complex generated by `simplices` (all faces added); num_nodes: one more than the "
          "largest id used unless given")
      .def_static(
          "from_ordered",
          [](const py::object& ranks) {
            std::vector<Cells> cells;
            std::size_t k = 0;
            for (const py::handle r : ranks)
              cells.push_back(cells_arg(r, "from_ordered(cells)[" + std::to_string(k++) + "]"));
            return SC::from_ordered(cells);
          },
          py::arg("cells"),
          "the complex whose rank-k simplices are cells[k] in that order (cells[0]: [[0], ..., "
          "[n-1]]; every face listed): another library's indexing")
      .def_static(
          "from_flat",
          [](const at::Tensor& simplices, const py::object& num_nodes) {
            require_integer_tensor(simplices, "from_flat(simplices)");
            if (simplices.dim() != 2)
              throw py::value_error("from_flat(simplices): expected shape (count, arity), got " +
                                    c10::str(simplices.sizes()));
            const auto flat = tensor_rows_flat(simplices);
            const Index n = num_nodes.is_none() ? -1 : node_id(num_nodes, "num_nodes");
            py::gil_scoped_release release;
            return SC::from_flat(flat.data(), static_cast<std::size_t>(simplices.size(0)),
                                 static_cast<int>(simplices.size(1)), n);
          },
          py::arg("simplices"), py::arg("num_nodes") = py::none(),
          "the complex generated by the rows of an integer tensor (a mesh's faces: (F, 3))")
      .def(
          "add_simplex",
          [](SC& sc, const py::object& s) { sc.add_simplex(cell_arg(s, "add_simplex(simplex)")); },
          py::arg("simplex"))
      .def(
          "add_simplices_from",
          [](SC& sc, const py::object& s) {
            sc.add_simplices(cells_arg(s, "add_simplices_from(simplices)"));
          },
          py::arg("simplices"))
      .def(
          "index",
          [](const SC& sc, const py::object& s) {
            const auto nodes = cell_arg(s, "index(simplex)");
            const auto id = sc.find(nodes);
            if (!id)
              throw py::key_error("simplex " + std::string(py::str(s)) + " is not in the complex");
            return *id;
          },
          py::arg("simplex"), "the id of a simplex within its rank (row of the operators)")
      .def("__contains__",
           [](const SC& sc, const py::object& s) { return sc.contains(cell_arg(s, "simplex")); })
      .def("simplex", &SC::simplex, py::arg("rank"), py::arg("id"))
      .def("faces", &SC::faces, py::arg("rank"), py::arg("id"), py::arg("face_rank"))
      .def("cofaces", &SC::cofaces, py::arg("rank"), py::arg("id"), py::arg("coface_rank"))
      .def("star", &SC::star, py::arg("rank"), py::arg("id"))
      .def("link", &SC::link, py::arg("rank"), py::arg("id"))
      .def("skeleton_complex", &SC::skeleton_complex, py::arg("rank"))
      .def(
          "weighted_hodge_laplacian_matrix",
          [](const SC& sc, int rank, const py::object& below, const py::object& above,
             const std::string& format, const py::object& dtype) {
            const std::string w = "SimplicialComplex.weighted_hodge_laplacian_matrix";
            const Eigen::VectorXd b =
                below.is_none() ? Eigen::VectorXd() : vector_arg(below, w + "(w_below)");
            const Eigen::VectorXd a =
                above.is_none() ? Eigen::VectorXd() : vector_arg(above, w + "(w_above)");
            return op(out_spec(format, dtype, w),
                      [&] { return sc.weighted_hodge_laplacian_matrix(rank, b, a); });
          },
          py::arg("rank"), py::arg("w_below") = py::none(), py::arg("w_above") = py::none(),
          TOPOS_OUT_ARGS, "B_k^T W_{k-1} B_k + B_{k+1} W_{k+1} B_{k+1}^T (None: unit weights)");
  def_oriented_operators(cls, "SimplicialComplex");
}

void bind_cell(py::module_& m) {
  using CX = CellComplex;
  py::class_<CX> cls(m, "CellComplex",
                     "A regular 2-dimensional cell complex (topos/core/cell_complex.hpp): nodes, "
                     "edges and 2-cells as vertex cycles, TopoNetX's order and orientation.");
  cls.def(py::init([](const py::object& cells, const py::object& num_nodes) {
            const Cells cs = cells_arg(cells, "CellComplex(cells)");
            CX cx(num_nodes_of(cs, num_nodes));
            for (const auto& c : cs) {
              if (c.size() == 2)
                cx.add_edge(c[0], c[1]);
              else
                cx.add_cell(c);
            }
            return cx;
          }),
          py::arg("cells") = py::list(), py::arg("num_nodes") = py::none(),
          "cells: 2 nodes make an edge, 3 or more a 2-cell (its boundary edges are added)")
      .def_static(
          "from_ordered",
          [](Index num_nodes, const py::object& edges, const py::object& cells) {
            Edges es = edges_arg(edges, "CellComplex.from_ordered(edges)");
            std::vector<CX::Edge> e;
            for (const auto& p : es) e.push_back({p[0], p[1]});
            return CX::from_ordered(num_nodes, e,
                                    cells_arg(cells, "CellComplex.from_ordered(cells)"));
          },
          py::arg("num_nodes"), py::arg("edges"), py::arg("cells"),
          "edges (oriented as given) and 2-cells in exactly the given order")
      .def("add_node", [](CX& cx) { return cx.add_nodes(1); })
      .def("add_nodes", &CX::add_nodes, py::arg("count"))
      .def("add_edge", &CX::add_edge, py::arg("u"), py::arg("v"))
      .def(
          "add_cell",
          [](CX& cx, const py::object& cell, int rank) {
            const auto c = cell_arg(cell, "CellComplex.add_cell(cell)");
            if (rank == 1) {
              if (c.size() != 2)
                throw py::value_error(
                    "CellComplex.add_cell: a rank-1 cell (an edge) has 2 nodes, "
                    "got " +
                    std::to_string(c.size()));
              cx.add_edge(c[0], c[1]);
            } else if (rank == 2) {
              cx.add_cell(c);
            } else {
              throw py::value_error("CellComplex.add_cell: rank " + std::to_string(rank) +
                                    " must be 1 (an edge) or 2 (a 2-cell)");
            }
          },
          py::arg("cell"), py::arg("rank") = 2)
      .def_property_readonly("edges", &CX::edges, "edges as (tail, head), in id order")
      .def("cell", &CX::cell, py::arg("id"), "the vertex cycle of 2-cell `id`");
  def_oriented_operators(cls, "CellComplex");
}

void bind_combinatorial(py::module_& m) {
  using CC = CombinatorialComplex<>;
  py::class_<CC> cls(m, "CombinatorialComplex",
                     "A combinatorial complex (topos/core/combinatorial_complex.hpp): node sets "
                     "with ranks monotone under inclusion, ids per rank in insertion order.");
  const auto add = [](CC& cc, const std::vector<Index>& c, int rank, const std::string& where) {
    if (rank == 0) {
      if (c.size() != 1)
        throw py::value_error(where + ": a rank-0 cell is one node, got " +
                              std::to_string(c.size()));
      if (c[0] >= cc.num_nodes()) cc.add_nodes(c[0] + 1 - cc.num_nodes());
      return c[0];
    }
    return cc.add_cell(c, rank).first;
  };
  cls.def(py::init(
              [add](const py::object& cells, const py::object& ranks, const py::object& num_nodes) {
                const Cells cs = cells_arg(cells, "CombinatorialComplex(cells)");
                std::vector<int> rk;
                if (ranks.is_none()) {
                  if (!cs.empty())
                    throw py::value_error(
                        "CombinatorialComplex(cells, ranks): ranks are required "
                        "with cells (one per cell, or one for all)");
                } else if (PyIndex_Check(ranks.ptr())) {
                  rk.assign(cs.size(), ranks.cast<int>());
                } else {
                  rk = ranks.cast<std::vector<int>>();
                  if (rk.size() != cs.size())
                    throw py::value_error(
                        "CombinatorialComplex(cells, ranks): " + std::to_string(cs.size()) +
                        " cells but " + std::to_string(rk.size()) + " ranks");
                }
                CC cc(num_nodes_of(cs, num_nodes));
                for (std::size_t i = 0; i < cs.size(); ++i)
                  add(cc, cs[i], rk[i], "CombinatorialComplex(cells)[" + std::to_string(i) + "]");
                return cc;
              }),
          py::arg("cells") = py::list(), py::arg("ranks") = py::none(),
          py::arg("num_nodes") = py::none(),
          "cells with their ranks (a list, or one int for all); nodes 0..n-1")
      .def(
          "add_cell",
          [add](CC& cc, const py::object& cell, int rank) {
            return add(cc, cell_arg(cell, "CombinatorialComplex.add_cell(cell)"), rank,
                       "CombinatorialComplex.add_cell");
          },
          py::arg("cell"), py::arg("rank"), "adds a cell (nodes must exist); returns its id")
      .def("add_nodes", &CC::add_nodes, py::arg("count"))
      .def_property_readonly("shape", [](const CC& c) { return shape_tuple(c.shape()); })
      .def_property_readonly("dim", &CC::dim)
      .def_property_readonly("num_nodes", &CC::num_nodes)
      .def("__len__", &CC::num_nodes)
      .def("num_cells", &CC::num_cells, py::arg("rank"))
      .def("skeleton", &CC::skeleton, py::arg("rank"))
      .def("cell_nodes", &CC::cell_nodes, py::arg("rank"), py::arg("id"))
      .def(
          "index",
          [](const CC& cc, const py::object& c) {
            const auto f = cc.find(cell_arg(c, "index(cell)"));
            if (!f)
              throw py::key_error("cell " + std::string(py::str(c)) + " is not in the complex");
            return py::make_tuple(f->rank, f->id);
          },
          py::arg("cell"), "(rank, id) of a cell given by its nodes")
      .def("__repr__", [](const CC& c) { return shape_repr("CombinatorialComplex", c); });
  const std::string name = "CombinatorialComplex";
  def_rank_pair_operator(
      cls, name, "incidence_matrix",
      [](const CC& c, int r, int to) { return c.incidence_matrix(r, to); },
      "n_rank x n_to_rank inclusion (TopoNetX's incidence_matrix(rank, to_rank))", py::arg("rank"),
      py::arg("to_rank"));
  def_rank_pair_operator(
      cls, name, "adjacency_matrix",
      [](const CC& c, int r, int via) { return c.adjacency_matrix(r, via); },
      "cells of `rank` sharing a cell of via_rank > rank (entry: how many)", py::arg("rank"),
      py::arg("via_rank"));
  def_rank_pair_operator(
      cls, name, "coadjacency_matrix",
      [](const CC& c, int r, int via) { return c.coadjacency_matrix(r, via); },
      "cells of `rank` sharing a cell of via_rank < rank (entry: how many)", py::arg("rank"),
      py::arg("via_rank"));
}

void bind_hypergraph(py::module_& m) {
  using HG = Hypergraph;
  py::class_<HG> cls(m, "Hypergraph",
                     "Nodes 0..n-1 and hyperedges (node sets, optional weights) in insertion "
                     "order (topos/core/hypergraph.hpp).");
  cls.def(py::init(
              [](const py::object& edges, const py::object& num_nodes, const py::object& weights) {
                const Cells cs = cells_arg(edges, "Hypergraph(hyperedges)");
                const Eigen::VectorXd w =
                    weights.is_none()
                        ? Eigen::VectorXd::Ones(static_cast<Eigen::Index>(cs.size()))
                        : vector_arg(weights, "Hypergraph(weights)", static_cast<Index>(cs.size()));
                HG h(num_nodes_of(cs, num_nodes));
                for (std::size_t i = 0; i < cs.size(); ++i)
                  h.add_hyperedge(cs[i], w[static_cast<Eigen::Index>(i)]);
                return h;
              }),
          py::arg("hyperedges") = py::list(), py::arg("num_nodes") = py::none(),
          py::arg("weights") = py::none())
      .def_static(
          "from_incidence_matrix",
          [](const py::object& b) {
            return HG::from_incidence_matrix(sparse_arg(b, "Hypergraph.from_incidence_matrix(B)"));
          },
          py::arg("B"), "hyperedge j holds the rows i with B[i, j] != 0 (node x hyperedge)")
      .def(
          "add_hyperedge",
          [](HG& h, const py::object& e, double w) {
            return h.add_hyperedge(cell_arg(e, "Hypergraph.add_hyperedge(nodes)"), w);
          },
          py::arg("nodes"), py::arg("weight") = 1.0)
      .def("add_nodes", &HG::add_nodes, py::arg("count"))
      .def_property_readonly("shape", [](const HG& h) { return shape_tuple(h.shape()); })
      .def_property_readonly("dim", &HG::dim)
      .def_property_readonly("num_nodes", &HG::num_nodes)
      .def_property_readonly("num_hyperedges", &HG::num_hyperedges)
      .def("__len__", &HG::num_nodes)
      .def("num_cells", &HG::num_cells, py::arg("rank"))
      .def("skeleton", &HG::skeleton, py::arg("rank"))
      .def("hyperedge", &HG::hyperedge, py::arg("id"))
      .def_property_readonly("weights",
                             [](const HG& h) {
                               const Eigen::VectorXd w = h.weights();
                               return vector_tensor(w);
                             })
      .def("node_degrees",
           [](const HG& h) {
             const Eigen::VectorXd d = h.node_degrees();
             return vector_tensor(d);
           })
      .def("hyperedge_sizes",
           [](const HG& h) {
             const Eigen::VectorXd d = h.hyperedge_sizes();
             return vector_tensor(d);
           })
      .def(
          "incidence_matrix",
          [](const HG& h, int rank, int to_rank, bool weighted, const std::string& format,
             const py::object& dtype) {
            return op(out_spec(format, dtype, "Hypergraph.incidence_matrix"),
                      [&] { return h.incidence_matrix(rank, to_rank, weighted); });
          },
          py::arg("rank") = 0, py::arg("to_rank") = 1, py::arg("weighted") = false, TOPOS_OUT_ARGS,
          "node x hyperedge membership (rank 0 to 1; 1 to 0 is its transpose)")
      .def("__repr__", [](const HG& h) { return shape_repr("Hypergraph", h); });
  def_rank_pair_operator(
      cls, "Hypergraph", "adjacency_matrix",
      [](const HG& h, int r, int via) { return h.adjacency_matrix(r, via); },
      "nodes sharing hyperedges (entry: how many)", py::arg("rank") = 0, py::arg("via_rank") = 1);
  def_rank_pair_operator(
      cls, "Hypergraph", "coadjacency_matrix",
      [](const HG& h, int r, int via) { return h.coadjacency_matrix(r, via); },
      "hyperedges sharing nodes (entry: how many)", py::arg("rank") = 1, py::arg("via_rank") = 0);
}

// A lifting f(num_nodes, edges, extra...) as name(num_nodes, edges, extra...), run without the
// GIL; `args` names the extra arguments.
template <class R, class... A, class... Extra>
void def_graph_lifting(py::module_& m, const char* name, R (*f)(Index, const Edges&, A...),
                       const char* doc, const Extra&... args) {
  const std::string where = std::string(name) + "(edges)";
  m.def(
      name,
      [where, name, f](Index n, const py::object& edges, A... a) {
        if (n < 0)
          throw py::value_error(std::string(name) + ": num_nodes " + std::to_string(n) +
                                " must be >= 0");
        const Edges e = edges_arg(edges, where);
        py::gil_scoped_release release;
        return f(n, e, a...);
      },
      py::arg("num_nodes"), py::arg("edges"), args..., doc);
}

void bind_liftings(py::module_& m) {
  def_graph_lifting(m, "clique_complex", &clique_complex,
                    "every clique of at most max_rank + 1 nodes as a simplex", py::arg("max_rank"));
  def_graph_lifting(m, "clique_lifting", &clique_lifting, "TopoBench's SimplicialCliqueLifting",
                    py::arg("complex_dim") = 3);
  def_graph_lifting(m, "cycle_basis", &cycle_basis,
                    "networkx's cycle_basis (>= 3.2), same cycles and order");
  def_graph_lifting(m, "khop_lifting", &khop_lifting,
                    "TopoBench's HypergraphKHopLifting: hyperedge v = the k-hop ball of v",
                    py::arg("k") = 1);
  def_graph_lifting(m, "neighborhood_hypergraph", &neighborhood_hypergraph,
                    "hyperedge v = v and its neighbours");
  // TopoBench's None (no limit) is -1 in C++.
  m.def(
      "cycle_lifting",
      [](Index n, const py::object& edges, const py::object& max_cell_length) {
        if (n < 0)
          throw py::value_error("cycle_lifting: num_nodes " + std::to_string(n) + " must be >= 0");
        const Edges e = edges_arg(edges, "cycle_lifting(edges)");
        const int len = max_cell_length.is_none() ? -1 : max_cell_length.cast<int>();
        py::gil_scoped_release release;
        return cycle_lifting(n, e, len);
      },
      py::arg("num_nodes"), py::arg("edges"), py::arg("max_cell_length") = 10,
      "TopoBench's CellCycleLifting (max_cell_length None: every basis cycle)");
  m.def("to_hypergraph", &to_hypergraph, py::arg("complex"),
        "every simplex of rank >= 1 as a hyperedge (TopoNetX's to_hypergraph)");
  m.def("to_combinatorial_complex", &to_combinatorial_complex, py::arg("complex"));
  m.def("to_cell_complex", &to_cell_complex, py::arg("complex"));
}

void bind_normalization(py::module_& parent) {
  py::module_ m = parent.def_submodule(
      "normalization", "toponetx.utils.normalization's functions (topos/core/normalization.hpp)");
  m.def(
      "compute_laplacian_normalized_matrix",
      [](const py::object& l, const std::string& format, const py::object& dtype) {
        const std::string w = "compute_laplacian_normalized_matrix";
        const SparseMatrix L = sparse_arg(l, w + "(L)");
        return op(out_spec(format, dtype, w),
                  [&] { return compute_laplacian_normalized_matrix(L); });
      },
      py::arg("L"), TOPOS_OUT_ARGS, "L / lambda_max(L)");
  m.def(
      "compute_x_laplacian_normalized_matrix",
      [](const py::object& l, const py::object& lx, const std::string& format,
         const py::object& dtype) {
        const std::string w = "compute_x_laplacian_normalized_matrix";
        const SparseMatrix L = sparse_arg(l, w + "(L)"), Lx = sparse_arg(lx, w + "(L_x)");
        return op(out_spec(format, dtype, w),
                  [&] { return compute_x_laplacian_normalized_matrix(L, Lx); });
      },
      py::arg("L"), py::arg("L_x"), TOPOS_OUT_ARGS, "L_x / lambda_max(L)");
  m.def(
      "compute_kipf_adjacency_normalized_matrix",
      [](const py::object& a, bool add_identity, double mult, const std::string& format,
         const py::object& dtype) {
        const std::string w = "compute_kipf_adjacency_normalized_matrix";
        const SparseMatrix A = sparse_arg(a, w + "(A)");
        return op(out_spec(format, dtype, w),
                  [&] { return compute_kipf_adjacency_normalized_matrix(A, add_identity, mult); });
      },
      py::arg("A"), py::arg("add_identity") = false, py::arg("identity_multiplier") = 1.0,
      TOPOS_OUT_ARGS, "D^-1/2 (|A| + m I)^T D^-1/2");
  m.def(
      "compute_xu_asymmetric_normalized_matrix",
      [](const py::object& b, bool is_sparse, const std::string& format, const py::object& dtype) {
        const std::string w = "compute_xu_asymmetric_normalized_matrix";
        const SparseMatrix B = sparse_arg(b, w + "(B)");
        return op(out_spec(format, dtype, w),
                  [&] { return compute_xu_asymmetric_normalized_matrix(B, is_sparse); });
      },
      py::arg("B"), py::arg("is_sparse") = true, TOPOS_OUT_ARGS, "D^-1 B");
  m.def(
      "compute_bunch_normalized_matrices",
      [](const py::object& b1, const py::object& b2, const std::string& format,
         const py::object& dtype) {
        const std::string w = "compute_bunch_normalized_matrices";
        const OutSpec out = out_spec(format, dtype, w);
        const SparseMatrix B1 = sparse_arg(b1, w + "(B1)"), B2 = sparse_arg(b2, w + "(B2)");
        std::array<SparseMatrix, 4> r;
        {
          py::gil_scoped_release release;
          r = compute_bunch_normalized_matrices(B1, B2);
        }
        return py::make_tuple(emit(r[0], out), emit(r[1], out), emit(r[2], out), emit(r[3], out));
      },
      py::arg("B1"), py::arg("B2"), TOPOS_OUT_ARGS, "(B1N, B1TN, B2N, B2TN)");
}

}  // namespace

}  // namespace topos::python

PYBIND11_MODULE(_C, m) {
  namespace tp = topos::python;
  namespace py = pybind11;
  m.doc() = "topos's C++ core (the package topos wraps it)";
  m.attr("__version__") = TOPOS_VERSION;
  // torch must be imported first: its Python types back the tensors this module returns.
  py::module_::import("torch");
  const py::object complex_error =
      py::register_local_exception<topos::ComplexError>(m, "ComplexError", PyExc_ValueError);
  complex_error.attr("__doc__") =
      "A misuse of a complex: bad node ids, repeated cells, a rank the complex does not have.";
  py::register_local_exception<topos::data::DataError>(m, "DataError", PyExc_RuntimeError)
      .attr("__doc__") = "A file or dataset that topos cannot read (the message names it).";
  // LibTorch's errors without their C++ backtrace.
  py::register_local_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const c10::IndexError& e) {
      PyErr_SetString(PyExc_IndexError, e.what_without_backtrace());
    } catch (const c10::ValueError& e) {
      PyErr_SetString(PyExc_ValueError, e.what_without_backtrace());
    } catch (const c10::TypeError& e) {
      PyErr_SetString(PyExc_TypeError, e.what_without_backtrace());
    } catch (const c10::Error& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what_without_backtrace());
    }
  });
  tp::bind_simplicial(m);
  tp::bind_cell(m);
  tp::bind_combinatorial(m);
  tp::bind_hypergraph(m);
  tp::bind_liftings(m);
  tp::bind_normalization(m);
  tp::bind_hopnet(m);
  tp::bind_schedule(m);
  tp::bind_zoo(m);
  tp::bind_topobench(m);
}
