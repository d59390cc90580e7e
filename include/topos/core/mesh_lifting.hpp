// topos/core/mesh_lifting.hpp
// Lifting several triangle meshes (objects) into one combinatorial complex:
//   rank 0  every vertex, objects concatenated in order (global id = object offset + local id);
//   rank 1  unique undirected edges, in order of first appearance when walking the global face
//           list and each face's directed pairs (a,b), (b,c), (c,a); oriented as first seen;
//   rank 2  every face in global order, oriented as in the mesh (optional: HOPNet adds faces per
//           frame instead);
//   object_rank  one cell per object holding all its vertices, in object order.
// Per-frame cells (contacts) go on top: take complex.mark() after lifting, add, then rollback.
#pragma once

#include "topos/core/combinatorial_complex.hpp"
#include "topos/mesh/triangle_mesh.hpp"

#include <array>
#include <stdexcept>
#include <vector>

namespace topos {

namespace detail {
// A flat open-addressing map from nonzero 64-bit keys to ids, for node-pair look-ups by the
// hundred thousand (HOPNet's edge ids), where a node-based std::unordered_map spends most of
// its time allocating.
class FlatKeyMap {
 public:
  explicit FlatKeyMap(std::size_t expected) {
    std::size_t cap = 16;
    int bits = 4;
    while (cap < 2 * expected) cap *= 2, ++bits;
    shift_ = 64 - bits;
    keys_.assign(cap, 0);
    vals_.resize(cap);
  }
  /// Returns (value, inserted): the existing value, or `v` newly stored.
  std::pair<std::int64_t, bool> emplace(std::uint64_t key, std::int64_t v) {
    // Fibonacci hashing: the product's top bits (the low ones repeat the keys' patterns).
    std::uint64_t x = key ^ (key >> 29);
    std::size_t i = static_cast<std::size_t>((x * 0x9e3779b97f4a7c15ULL) >> shift_);
    while (keys_[i] != 0) {
      if (keys_[i] == key) return {vals_[i], false};
      i = (i + 1) & (keys_.size() - 1);
    }
    if (2 * (++size_) > keys_.size()) throw std::logic_error("FlatKeyMap: over capacity");
    keys_[i] = key;
    vals_[i] = v;
    return {v, true};
  }

 private:
  std::vector<std::uint64_t> keys_;
  std::vector<std::int64_t> vals_;
  std::size_t size_ = 0;
  int shift_ = 60;
};
}  // namespace detail

struct LiftOptions {
  bool faces = true;    ///< add rank-2 cells for every face
  int object_rank = 3;  ///< rank of the object cells (HOPNet: 4); 0 disables them
  LiftOptions& with_faces(bool v) {
    faces = v;
    return *this;
  }
  LiftOptions& with_object_rank(int r) {
    object_rank = r;
    return *this;
  }
};

template <class Options = DefaultComplexOptions>
struct LiftedMeshes {
  using Index = typename Options::Index;
  CombinatorialComplex<Options> complex;
  std::vector<Index> node_offset;  ///< O+1 offsets of each object's nodes
  std::vector<Index> face_offset;  ///< O+1 offsets into the global face list
  Eigen::Matrix<Index, Eigen::Dynamic, 3, Eigen::RowMajor>
      faces;                                ///< global face list (global node ids)
  std::vector<std::array<Index, 2>> edges;  ///< edge id -> first-seen (a, b)
  std::vector<Index> node_object;           ///< object of each node
  int object_rank = 0;

  Index num_objects() const { return static_cast<Index>(node_offset.size()) - 1; }
};

template <class Options = DefaultComplexOptions>
LiftedMeshes<Options> lift_meshes(const std::vector<TriangleMesh>& meshes,
                                  const LiftOptions& opt = {}) {
  using Index = typename Options::Index;
  if (opt.object_rank != 0 && opt.object_rank < (opt.faces ? 3 : 2)) {
    throw ComplexError("lift_meshes: object rank " + std::to_string(opt.object_rank) +
                       " must be above the face rank 2");
  }
  LiftedMeshes<Options> out;
  out.object_rank = opt.object_rank;
  Index n_nodes = 0, n_faces = 0;
  out.node_offset.push_back(0);
  out.face_offset.push_back(0);
  for (const TriangleMesh& m : meshes) {
    m.validate();
    n_nodes += m.num_vertices();
    n_faces += m.num_faces();
    out.node_offset.push_back(n_nodes);
    out.face_offset.push_back(n_faces);
  }
  out.faces.resize(n_faces, 3);
  out.node_object.resize(static_cast<std::size_t>(n_nodes));
  for (std::size_t o = 0; o < meshes.size(); ++o) {
    const Index off = out.node_offset[o];
    out.faces.middleRows(out.face_offset[o], meshes[o].num_faces()) =
        (meshes[o].faces.array() + off).matrix();
    for (Index v = off; v < out.node_offset[o + 1]; ++v)
      out.node_object[static_cast<std::size_t>(v)] = static_cast<Index>(o);
  }

  if (n_nodes >= (Index(1) << 31)) throw ComplexError("lift_meshes: more than 2^31 nodes");
  auto& cc = out.complex;
  cc.add_nodes(n_nodes);
  // Unique edges in order of first appearance. Bucket the 3F directed pairs by their smaller node
  // (mesh-local, so cache friendly), find first occurrences within each small bucket, then emit
  // in position order.
  const std::size_t n_pairs = static_cast<std::size_t>(n_faces) * 3;
  std::vector<Index> bucket(static_cast<std::size_t>(n_nodes) + 1, 0);
  const auto pair_at = [&](std::size_t pos) {
    const Index f = static_cast<Index>(pos / 3);
    const int k = static_cast<int>(pos % 3);
    return std::pair<Index, Index>{out.faces(f, k), out.faces(f, (k + 1) % 3)};
  };
  for (std::size_t pos = 0; pos < n_pairs; ++pos) {
    auto [a, b] = pair_at(pos);
    ++bucket[static_cast<std::size_t>(std::min(a, b)) + 1];
  }
  for (std::size_t v = 0; v < static_cast<std::size_t>(n_nodes); ++v) bucket[v + 1] += bucket[v];
  // Positions of the pairs, grouped by smaller node, ascending within each group.
  std::vector<Index> entries(n_pairs);
  {
    std::vector<Index> fill(bucket.begin(), bucket.end() - 1);
    for (std::size_t pos = 0; pos < n_pairs; ++pos) {
      auto [a, b] = pair_at(pos);
      entries[static_cast<std::size_t>(fill[static_cast<std::size_t>(std::min(a, b))]++)] =
          static_cast<Index>(pos);
    }
  }
  // Within a group, a pair whose larger node appeared before is a repeated edge. Two faces with
  // the same three nodes share an edge and its opposite node: that is how duplicates show.
  const auto larger = [&](Index pos) {
    auto [a, b] = pair_at(static_cast<std::size_t>(pos));
    return std::max(a, b);
  };
  const auto opposite = [&](Index pos) { return out.faces(pos / 3, (pos % 3 + 2) % 3); };
  std::vector<char> first(n_pairs, 0);
  for (std::size_t v = 0; v < static_cast<std::size_t>(n_nodes); ++v) {
    for (Index i = bucket[v]; i < bucket[v + 1]; ++i) {
      const Index pi = entries[static_cast<std::size_t>(i)], li = larger(pi);
      bool seen = false;
      for (Index j = bucket[v]; j < i; ++j) {
        const Index pj = entries[static_cast<std::size_t>(j)];
        if (larger(pj) != li) continue;
        seen = true;
        if (opt.faces && opposite(pj) == opposite(pi)) {
          const Index f = pi / 3;
          Index o = 0;
          while (out.face_offset[static_cast<std::size_t>(o) + 1] <= f) ++o;
          throw MeshError("lift_meshes: face " +
                          std::to_string(f - out.face_offset[static_cast<std::size_t>(o)]) +
                          " of object " + std::to_string(o) + " duplicates an earlier face");
        }
      }
      if (!seen) first[static_cast<std::size_t>(pi)] = 1;
    }
  }
  std::size_t n_edges = 0;
  for (char c : first) n_edges += static_cast<std::size_t>(c);
  out.edges.reserve(n_edges);
  for (std::size_t pos = 0; pos < n_pairs; ++pos) {
    if (!first[pos]) continue;
    auto [a, b] = pair_at(pos);
    out.edges.push_back({a, b});
  }
  static_assert(sizeof(std::array<Index, 2>) == 2 * sizeof(Index),
                "edges must be contiguous pairs");
  cc.add_cells_trusted(out.edges.empty() ? nullptr : out.edges.front().data(), n_edges, 2, 1);
  if (opt.faces) {
    // Duplicate faces were rejected with the edges above.
    cc.add_cells_trusted(out.faces.data(), static_cast<std::size_t>(n_faces), 3, 2);
  }
  if (opt.object_rank > 0) {
    for (std::size_t o = 0; o < meshes.size(); ++o) {
      std::vector<Index> nodes;
      for (Index v = out.node_offset[o]; v < out.node_offset[o + 1]; ++v) nodes.push_back(v);
      // An object holds all its mesh's nodes and nothing else, so it can only break the rank
      // condition by equalling one of its own faces or edges (a one-triangle object).
      if (auto c = nodes.size() <= 3 ? cc.find(nodes) : std::nullopt) {
        throw ComplexError("lift_meshes: object " + std::to_string(o) +
                           " has the same nodes as a cell of rank " + std::to_string(c->rank) +
                           "; it already exists at rank " + std::to_string(c->rank));
      }
      cc.add_cell_trusted(nodes.data(), nodes.size(), opt.object_rank);
    }
  }
  return out;
}

#ifdef TOPOS_CORE_COMPILED  // compiled once (src/core.cpp; combinatorial_complex.hpp)
extern template LiftedMeshes<DefaultComplexOptions> lift_meshes<DefaultComplexOptions>(
    const std::vector<TriangleMesh>&, const LiftOptions&);
#endif

}  // namespace topos
