// topos/core/neighborhood.hpp
// A Neighborhood is what message passing consumes: directed (source cell -> target cell) index
// pairs between two ranks, with optional values and roles. Its direction is explicit, so nobody
// ever transposes an incidence matrix by hand. Std + Eigen only.
#pragma once

#include "topos/core/combinatorial_complex.hpp"

#include <cstdint>
#include <string>
#include <vector>

namespace topos {

struct Neighborhood {
  std::string name;
  int source_rank = 0;
  int target_rank = 0;
  std::vector<std::int64_t> source;  ///< source cell of each pair
  std::vector<std::int64_t> target;  ///< target cell of each pair
  std::vector<double> values;        ///< empty, or one value per pair
  /// Empty, or per pair the factor a weighted message's gradient is multiplied by instead of
  /// its value. Reproduces implementations that compute a message once per duplicate pair and
  /// write the copies into one row with index_put_: the forward keeps one copy (value 1) but
  /// the backward sends the row's gradient to each of the k copies (factor k).
  std::vector<double> backward_values;
  std::vector<std::int8_t> roles;  ///< empty, or one role per pair (0 = none)
  std::int64_t num_source = 0;
  std::int64_t num_target = 0;

  std::int64_t nnz() const { return static_cast<std::int64_t>(source.size()); }

  /// The same pairs with source and target swapped (messages flowing the other way).
  Neighborhood reversed(std::string new_name = {}) const {
    Neighborhood n = *this;
    n.name = new_name.empty() ? name + "^T" : std::move(new_name);
    std::swap(n.source, n.target);
    std::swap(n.source_rank, n.target_rank);
    std::swap(n.num_source, n.num_target);
    return n;
  }

  /// Throws ComplexError when sizes disagree or an index is out of range.
  void validate() const {
    const auto fail = [&](const std::string& why) {
      throw ComplexError("neighborhood '" + name + "': " + why);
    };
    if (source.size() != target.size()) fail("source and target have different lengths");
    if (!values.empty() && values.size() != source.size())
      fail("values must be empty or one per pair");
    if (!roles.empty() && roles.size() != source.size())
      fail("roles must be empty or one per pair");
    if (!backward_values.empty() && backward_values.size() != source.size())
      fail("backward values must be empty or one per pair");
    for (std::size_t k = 0; k < source.size(); ++k) {
      if (source[k] < 0 || source[k] >= num_source)
        fail("source index " + std::to_string(source[k]) + " out of range");
      if (target[k] < 0 || target[k] >= num_target)
        fail("target index " + std::to_string(target[k]) + " out of range");
    }
  }
};

/// Messages from cells of rank `from` to cells of rank `to` along set inclusion (either
/// direction), carrying declared values and roles. Pairs are ordered by (upper, lower) cell id.
template <class Options>
Neighborhood incidence_neighborhood(const CombinatorialComplex<Options>& cc, int from, int to,
                                    std::string name = {}) {
  if (from == to)
    throw ComplexError("incidence_neighborhood: ranks must differ (got " + std::to_string(from) +
                       ")");
  Neighborhood n;
  n.name = name.empty()
               ? "B" + std::to_string(std::min(from, to)) + std::to_string(std::max(from, to))
               : std::move(name);
  n.source_rank = from;
  n.target_rank = to;
  n.num_source = cc.size(from);
  n.num_target = cc.size(to);
  bool any_value = false, any_role = false;
  cc.for_each_inclusion(std::min(from, to), std::max(from, to),
                        [&](std::int64_t lo, std::int64_t hi, double v, int role) {
                          n.source.push_back(from < to ? lo : hi);
                          n.target.push_back(from < to ? hi : lo);
                          n.values.push_back(v);
                          n.roles.push_back(static_cast<std::int8_t>(role));
                          any_value |= (v != 1.0);
                          any_role |= (role != 0);
                        });
  if (!any_value) n.values.clear();
  if (!any_role) n.roles.clear();
  return n;
}

/// A neighborhood from a sparse matrix whose rows are targets and columns are sources.
template <class Scalar, int Flags>
Neighborhood neighborhood_from_matrix(const Eigen::SparseMatrix<Scalar, Flags, std::int64_t>& m,
                                      int source_rank, int target_rank, std::string name) {
  Neighborhood n;
  n.name = std::move(name);
  n.source_rank = source_rank;
  n.target_rank = target_rank;
  n.num_target = m.rows();
  n.num_source = m.cols();
  for (Eigen::Index k = 0; k < m.outerSize(); ++k) {
    for (typename Eigen::SparseMatrix<Scalar, Flags, std::int64_t>::InnerIterator it(m, k); it;
         ++it) {
      n.target.push_back(it.row());
      n.source.push_back(it.col());
      n.values.push_back(static_cast<double>(it.value()));
    }
  }
  return n;
}

/// Messages between cells of rank r that share a cell of rank `via` (above: adjacency, below:
/// coadjacency); values are the number of shared cells.
template <class Options>
Neighborhood adjacency_neighborhood(const CombinatorialComplex<Options>& cc, int r, int via,
                                    std::string name = {}) {
  auto m = via > r ? cc.adjacency_matrix(r, via) : cc.coadjacency_matrix(r, via);
  if (name.empty()) name = (via > r ? "A" : "coA") + std::to_string(r) + std::to_string(via);
  return neighborhood_from_matrix(m, r, r, std::move(name));
}

#ifdef TOPOS_CORE_COMPILED  // compiled once (src/core.cpp; combinatorial_complex.hpp)
extern template Neighborhood incidence_neighborhood<DefaultComplexOptions>(
    const CombinatorialComplex<DefaultComplexOptions>&, int, int, std::string);
extern template Neighborhood adjacency_neighborhood<DefaultComplexOptions>(
    const CombinatorialComplex<DefaultComplexOptions>&, int, int, std::string);
#endif

}  // namespace topos
