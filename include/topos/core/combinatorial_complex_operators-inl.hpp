// topos/core/combinatorial_complex_operators-inl.hpp
// The definitions of CombinatorialComplex's operators (combinatorial_complex.hpp): the inclusions
// between two ranks enumerated once (each subset through its smallest node), the incidence matrix
// filled as CSR directly, the signed incidence of simplicial cells, and the adjacency and
// coadjacency counts of shared cells without forming B Bᵀ.
#pragma once

#include "topos/core/combinatorial_complex.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace topos {

template <class Options>
template <class F>
inline void CombinatorialComplex<Options>::for_each_inclusion(int lo, int hi, F&& visit) const {
  require_rank(lo, "incidence");
  require_rank(hi, "incidence");
  if (lo >= hi)
    throw ComplexError("incidence: lower rank " + std::to_string(lo) + " must be below " +
                       std::to_string(hi));
  const Rank& U = ranks_[static_cast<std::size_t>(hi)];
  if (lo == 0 && U.declared.empty()) {
    // Every node of a cell, ascending (cells store their nodes sorted), value 1: no buffer.
    for (Index j = 0; j + 1 < static_cast<Index>(U.offsets.size()); ++j)
      for (Index k = U.offsets[static_cast<std::size_t>(j)];
           k < U.offsets[static_cast<std::size_t>(j) + 1]; ++k)
        visit(U.nodes[static_cast<std::size_t>(k)], j, Scalar(1), 0);
    return;
  }
  const MinIndex* M = lo > 0 ? &min_index(lo) : nullptr;
  const Rank& L = ranks_[static_cast<std::size_t>(lo)];
  std::vector<std::pair<Index, std::pair<Scalar, int>>> found;
  for (Index j = 0; j + 1 < static_cast<Index>(U.offsets.size()); ++j) {
    found.clear();
    const Index* b = U.nodes.data() + U.offsets[static_cast<std::size_t>(j)];
    const Index* e = U.nodes.data() + U.offsets[static_cast<std::size_t>(j) + 1];
    if (lo == 0) {
      for (const Index* p = b; p != e; ++p) found.push_back({*p, {Scalar(1), 0}});
    } else {
      // Each subset is found once: through its smallest node.
      for (const Index* p = b; p != e; ++p) {
        for (Index k = M->offsets[static_cast<std::size_t>(*p)];
             k < M->offsets[static_cast<std::size_t>(*p) + 1]; ++k) {
          const Index id = M->ids[static_cast<std::size_t>(k)];
          const Index* lb = L.nodes.data() + L.offsets[static_cast<std::size_t>(id)];
          const Index* le = L.nodes.data() + L.offsets[static_cast<std::size_t>(id) + 1];
          if (includes(b, e, lb, le)) found.push_back({id, {Scalar(1), 0}});
        }
      }
      if (found.size() > 1)
        std::sort(found.begin(), found.end(), [](auto& x, auto& y) { return x.first < y.first; });
    }
    for (Index k = U.declared_offsets[static_cast<std::size_t>(j)];
         k < U.declared_offsets[static_cast<std::size_t>(j) + 1]; ++k) {
      const Declared& d = U.declared[static_cast<std::size_t>(k)];
      if (d.rank != lo) continue;
      auto it = std::lower_bound(found.begin(), found.end(), d.id,
                                 [](auto& x, Index v) { return x.first < v; });
      if (it != found.end() && it->first == d.id) it->second = {d.value, d.role};
    }
    for (auto& f : found) visit(f.first, j, f.second.first, f.second.second);
  }
}

template <class Options>
inline auto CombinatorialComplex<Options>::incidence_matrix(int r, int s) const -> SparseMatrix {
  if (r == s)
    throw ComplexError("incidence_matrix: ranks must differ (got " + std::to_string(r) + " twice)");
  const int lo = std::min(r, s), hi = std::max(r, s);
  require_rank(lo, "incidence_matrix");  // before ranks_[hi] is read below
  require_rank(hi, "incidence_matrix");
  // The visit order (upper cells in order, lower ids ascending) is the CSR of the hi × lo
  // matrix: fill it directly; the lo × hi one is its transpose (Eigen's counting sort).
  // Filled in place (no intermediate arrays to copy: at 50k nodes the copies and their page
  // faults cost as much as the enumeration).
  SparseMatrix up(size(hi), size(lo));
  auto& data = up.data();
  data.reserve(lo == 0
                   ? static_cast<Eigen::Index>(ranks_[static_cast<std::size_t>(hi)].nodes.size())
                   : 3 * static_cast<Eigen::Index>(size(hi)));
  std::int64_t* outer = up.outerIndexPtr();
  for_each_inclusion(lo, hi, [&](Index i, Index j, Scalar v, int) {
    data.append(v, static_cast<Eigen::Index>(i));
    ++outer[j + 1];
  });
  for (Index j = 0; j < size(hi); ++j) outer[j + 1] += outer[j];
  if (r > s) return up;
  return SparseMatrix(up.transpose());
}

template <class Options>
inline auto CombinatorialComplex<Options>::signed_incidence_matrix(int r, int s) const
    -> SparseMatrix {
  if (s != r + 1)
    throw ComplexError("signed_incidence_matrix: needs s = r + 1 (got " + std::to_string(r) + ", " +
                       std::to_string(s) + ")");
  require_rank(r, "signed_incidence_matrix");
  require_rank(s, "signed_incidence_matrix");
  std::vector<Eigen::Triplet<Scalar, std::int64_t>> t;
  const Rank& U = ranks_[static_cast<std::size_t>(s)];
  for (Index j = 0; j < size(s); ++j) {
    const std::vector<Index> up = oriented_nodes(s, j);
    if (static_cast<int>(up.size()) != s + 1) {
      throw ComplexError("signed_incidence_matrix: cell " + std::to_string(j) + " of rank " +
                         std::to_string(s) + " has " + std::to_string(up.size()) +
                         " nodes; signed incidence needs simplicial cells");
    }
    (void)U;
    for (std::size_t i = 0; i < up.size(); ++i) {
      std::vector<Index> face;
      for (std::size_t k = 0; k < up.size(); ++k)
        if (k != i) face.push_back(up[k]);
      auto c = find(face);
      if (!c || c->rank != r) continue;
      const std::vector<Index> lo = oriented_nodes(r, c->id);
      const int sign = ((i % 2) ? -1 : 1) * permutation_parity(face, lo);
      t.emplace_back(c->id, j, static_cast<Scalar>(sign));
    }
  }
  SparseMatrix m(size(r), size(s));
  m.setFromTriplets(t.begin(), t.end());
  return m;
}

template <class Options>
inline auto CombinatorialComplex<Options>::adjacency_matrix(int r, int via) const -> SparseMatrix {
  if (via <= r)
    throw ComplexError("adjacency_matrix: via rank " + std::to_string(via) +
                       " must be above rank " + std::to_string(r));
  std::vector<Index> group_offsets{0}, members;
  Index current = 0;
  for_each_inclusion(r, via, [&](Index lo, Index hi, Scalar, int) {
    while (current < hi) {
      group_offsets.push_back(static_cast<Index>(members.size()));
      ++current;
    }
    members.push_back(lo);
  });
  while (current < size(via)) {
    group_offsets.push_back(static_cast<Index>(members.size()));
    ++current;
  }
  group_offsets.push_back(static_cast<Index>(members.size()));
  return pair_counts(group_offsets, members, size(r));
}

template <class Options>
inline auto CombinatorialComplex<Options>::coadjacency_matrix(int r, int via) const
    -> SparseMatrix {
  if (via >= r)
    throw ComplexError("coadjacency_matrix: via rank " + std::to_string(via) +
                       " must be below rank " + std::to_string(r));
  // Group the upper cells (rank r) by each shared lower cell (rank via): a counting sort.
  std::vector<std::pair<Index, Index>> inc;
  for_each_inclusion(via, r, [&](Index lo, Index hi, Scalar, int) { inc.push_back({lo, hi}); });
  std::vector<Index> group_offsets(static_cast<std::size_t>(size(via)) + 1, 0), members(inc.size());
  for (auto& p : inc) ++group_offsets[static_cast<std::size_t>(p.first) + 1];
  for (std::size_t i = 0; i + 1 < group_offsets.size(); ++i)
    group_offsets[i + 1] += group_offsets[i];
  std::vector<Index> fill(group_offsets.begin(), group_offsets.end() - 1);
  for (auto& p : inc)
    members[static_cast<std::size_t>(fill[static_cast<std::size_t>(p.first)]++)] = p.second;
  return pair_counts(group_offsets, members, size(r));
}

template <class Options>
inline int CombinatorialComplex<Options>::permutation_parity(const std::vector<Index>& a,
                                                             const std::vector<Index>& b) {
  // Parity of the permutation taking b to a (same node set).
  std::vector<Index> p(a.size());
  for (std::size_t i = 0; i < a.size(); ++i)
    p[i] = static_cast<Index>(std::find(b.begin(), b.end(), a[i]) - b.begin());
  int parity = 1;
  for (std::size_t i = 0; i < p.size(); ++i)
    for (std::size_t j = i + 1; j < p.size(); ++j)
      if (p[i] > p[j]) parity = -parity;
  return parity;
}

template <class Options>
inline auto CombinatorialComplex<Options>::pair_counts(const std::vector<Index>& offsets,
                                                       const std::vector<Index>& members, Index n)
    -> SparseMatrix {
  // Invert the membership (cell -> its groups) by a counting sort, then emit each row's
  // co-members sorted and counted: CSR directly, no triplet sort.
  std::vector<Index> gstart(static_cast<std::size_t>(n) + 1, 0), groups(members.size());
  for (Index m : members) ++gstart[static_cast<std::size_t>(m) + 1];
  for (std::size_t i = 0; i + 1 < gstart.size(); ++i) gstart[i + 1] += gstart[i];
  {
    std::vector<Index> fill(gstart.begin(), gstart.end() - 1);
    for (std::size_t g = 0; g + 1 < offsets.size(); ++g)
      for (Index a = offsets[g]; a < offsets[g + 1]; ++a)
        groups[static_cast<std::size_t>(
            fill[static_cast<std::size_t>(members[static_cast<std::size_t>(a)])]++)] =
            static_cast<Index>(g);
  }
  // At most Σ_g |g|(|g| - 1) entries (before merging repeats): reserve that, fill in place.
  std::int64_t bound = 0;
  for (std::size_t g = 0; g + 1 < offsets.size(); ++g)
    bound += (offsets[g + 1] - offsets[g]) * (offsets[g + 1] - offsets[g] - 1);
  SparseMatrix m(n, n);
  auto& data = m.data();
  data.reserve(static_cast<Eigen::Index>(bound));
  std::int64_t* outer = m.outerIndexPtr();
  std::vector<Index> row;
  for (Index i = 0; i < n; ++i) {
    row.clear();
    for (Index k = gstart[static_cast<std::size_t>(i)]; k < gstart[static_cast<std::size_t>(i) + 1];
         ++k) {
      const auto g = static_cast<std::size_t>(groups[static_cast<std::size_t>(k)]);
      for (Index a = offsets[g]; a < offsets[g + 1]; ++a)
        if (members[static_cast<std::size_t>(a)] != i)
          row.push_back(members[static_cast<std::size_t>(a)]);
    }
    std::sort(row.begin(), row.end());
    for (std::size_t a = 0; a < row.size();) {
      std::size_t b = a;
      while (b < row.size() && row[b] == row[a]) ++b;
      data.append(static_cast<Scalar>(b - a), static_cast<Eigen::Index>(row[a]));
      a = b;
    }
    outer[i + 1] = static_cast<std::int64_t>(data.size());
  }
  return m;
}

}  // namespace topos
