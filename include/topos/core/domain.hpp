// topos/core/domain.hpp
// The one concept every topological domain models (SimplicialComplex, CellComplex,
// CombinatorialComplex, Hypergraph), so operator, lifting, nn and batching code can take any
// of them. A Domain D has rank-indexed cells with dense ids 0..num_cells(r)-1 per rank, node
// ids being the rank-0 ids, and:
//   int D::dim() const                                   highest rank holding cells (-1: empty)
//   std::vector<Index> D::shape() const                  num_cells of ranks 0..dim()
//   Index D::num_cells(int rank) const                   0 for ranks without cells
//   std::vector<std::vector<Index>> D::skeleton(int r)   the cells of rank r as node lists, id
//     order
//   SparseMatrix D::inclusion_matrix(int r, int s)           n_r x n_s unsigned inclusion (r != s)
//   SparseMatrix D::adjacency_matrix_via(int r, int via)     via > r: off-diagonal |B||B|^T, counts
//   SparseMatrix D::coadjacency_matrix_via(int r, int via)   via < r: off-diagonal |B|^T|B|, counts
// (the neighbourhood functions, TopoNetX's CombinatorialComplex semantics; the combinatorial
// complex and the hypergraph also have them under TopoNetX's names, incidence_matrix(r, s),
// adjacency_matrix(r, via), coadjacency_matrix(r, via)). The simplicial and cell complexes have
// TopoNetX's oriented vocabulary instead: incidence_matrix(rank, Signed), up/down/
// hodge_laplacian_matrix(rank, signed), adjacency/coadjacency_matrix(rank, Signed), normalized_
// laplacian_matrix(rank); `Signed` is a type of its own and an int or a bool there does not
// compile, so a sign is never read as a rank or the reverse. Std + Eigen only (C++17: a trait, not
// a C++20 concept).
#pragma once

#include "topos/core/cell_complex.hpp"
#include "topos/core/combinatorial_complex.hpp"
#include "topos/core/hypergraph.hpp"
#include "topos/core/simplicial_complex.hpp"
#include "topos/core/sparse_matrix.hpp"

#include <type_traits>
#include <utility>
#include <vector>

namespace topos {

namespace detail {
template <class D, class = void>
struct is_domain_impl : std::false_type {};
template <class D>
struct is_domain_impl<D,
                      std::void_t<decltype(std::declval<const D&>().dim()),
                                  decltype(std::declval<const D&>().shape()),
                                  decltype(std::declval<const D&>().num_cells(0)),
                                  decltype(std::declval<const D&>().skeleton(0)),
                                  decltype(std::declval<const D&>().inclusion_matrix(0, 1)),
                                  decltype(std::declval<const D&>().adjacency_matrix_via(0, 1)),
                                  decltype(std::declval<const D&>().coadjacency_matrix_via(1, 0))>>
    : std::bool_constant<
          std::is_convertible_v<decltype(std::declval<const D&>().inclusion_matrix(0, 1)),
                                SparseMatrix> &&
          std::is_convertible_v<decltype(std::declval<const D&>().num_cells(0)), std::int64_t>> {};
}  // namespace detail

/// True when D models the Domain concept above.
template <class D>
inline constexpr bool is_domain_v = detail::is_domain_impl<D>::value;

static_assert(is_domain_v<SimplicialComplex>);
static_assert(is_domain_v<CellComplex>);
static_assert(is_domain_v<CombinatorialComplex<>>);
static_assert(is_domain_v<Hypergraph>);

/// Euler characteristic sum_r (-1)^r n_r of any domain.
template <class D, class = std::enable_if_t<is_domain_v<D>>>
std::int64_t euler_characteristic(const D& d) {
  std::int64_t chi = 0;
  for (int r = 0; r <= d.dim(); ++r)
    chi += (r % 2 ? -1 : 1) * static_cast<std::int64_t>(d.num_cells(r));
  return chi;
}

}  // namespace topos
