// python/src/convert.hpp
// What crosses between Python and topos in the extension topos._C: torch tensors through
// torch's own pybind11 caster (no copy), topos's sparse operators out as torch sparse COO / CSR,
// dense tensors or scipy.sparse (the `format=` and `dtype=` every operator method takes), and
// arguments in (sparse matrices from torch COO / CSR or scipy.sparse, cells and edges from lists
// or integer tensors) with a Python exception naming the argument when one does not fit.
#pragma once

#include "topos/core/sparse_matrix.hpp"
#include "topos/nn/sparse_operator.hpp"

#include <torch/csrc/Dtype.h>
#include <torch/csrc/autograd/python_variable.h>
#include <torch/csrc/utils/pybind.h>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace topos::python {

namespace py = pybind11;
using Index = std::int64_t;
using Cells = std::vector<std::vector<Index>>;
using Edges = std::vector<std::array<Index, 2>>;

/// How an operator is returned: torch sparse COO (coalesced; TopoModelX's users pass these),
/// torch sparse CSR, a dense torch tensor, or scipy.sparse.csr_matrix (TopoNetX's type).
enum class Format { coo, csr, dense, scipy };

struct OutSpec {
  Format format = Format::coo;
  at::ScalarType dtype = at::kDouble;
};

/// `format` and `dtype` as a method received them; dtype None is torch's default dtype for the
/// torch formats and float64 for scipy (TopoNetX's). `where` names the method in errors.
OutSpec out_spec(const std::string& format, const py::object& dtype, const std::string& where);

/// The operator in the requested form (called with the GIL held).
py::object emit(const SparseMatrix& m, const OutSpec& out);

/// A sparse matrix argument: a torch sparse COO or CSR tensor (any real dtype, any device) or a
/// scipy.sparse matrix; a dense tensor or array is a TypeError that says to pass x.to_sparse().
SparseMatrix sparse_arg(const py::handle& obj, const std::string& arg);

/// A list of cells, each a list of integer node ids (or a 2-D integer tensor / array, one cell
/// per row). `arg` names the argument in errors (e.g. "SimplicialComplex(simplices)").
Cells cells_arg(const py::handle& obj, const std::string& arg);
/// One cell: a list of integer node ids (or a 1-D integer tensor).
std::vector<Index> cell_arg(const py::handle& obj, const std::string& arg);
/// Edges of a graph: a list of (u, v) pairs, or an integer tensor or array of shape (2, E) (PyG's
/// edge_index).
Edges edges_arg(const py::handle& obj, const std::string& arg);
/// A real vector (tensor, array or list of numbers) of `expected` entries (-1: any).
Eigen::VectorXd vector_arg(const py::handle& obj, const std::string& arg, Index expected = -1);

/// An operator argument as a SparseOperator: torch sparse COO (coalesced: its values tensor is
/// used as is) or CSR, scipy.sparse (float64, then `dtype`), or a prepared topos.nn.SparseOperator
/// (schedule.cpp).
nn::SparseOperator operator_arg(const py::handle& obj, const std::string& arg,
                                at::ScalarType dtype);

/// A SparseOperator as a torch sparse COO tensor (coalesced; its values tensor, so gradients
/// through it reach the operator's values); `who` names it when it is held as factors only.
at::Tensor operator_out(const nn::SparseOperator& a, const std::string& who);

/// TopoNetX's `signed`: exactly True or False (an int there is a rank passed by mistake).
Signed signed_arg(const py::handle& obj, const std::string& where);

/// Python's name of obj's type ("int", "torch.Tensor", ...), for messages.
std::string type_name(const py::handle& obj);

}  // namespace topos::python
