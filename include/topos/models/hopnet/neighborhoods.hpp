// topos/models/hopnet/neighborhoods.hpp
// The neighbourhoods (incidences and adjacencies) of one frame's complex that HOPNet's schedule
// and its ablations read (hopnet_neighborhoods).
#pragma once

#include "topos/core/neighborhood.hpp"
#include "topos/models/hopnet/frame.hpp"
#include "topos/models/hopnet/geometry.hpp"
#include "topos/models/hopnet/lifting_options.hpp"
#include "topos/models/namespace_aliases.hpp"

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace topos::models::hopnet {

/// The neighbourhoods HOPNet's schedule reads, with explicit directions:
///   B02 (0→2), B12 (1→2), B42 (4→2: each face receives its object), B23neg / B23pos (2→3,
///   values: the half of the contact's face message this pair feeds), B32 (3→2, roles −1/+1),
///   B24 (2→4), B04 (0→4), B40 (4→0).
/// In reference mode B23neg/B23pos carry the reference's role-mixing buffer (neg(f), pos(f) per
/// face) and, as backward values, the reference's gradient multiplicity (the number of
/// contacts in which the face has that role); in native mode the pair's own role.
/// The ablations add (models/ablations.py): A010 (0→0, nodes sharing a rank-1 cell,
/// spokes included; the reference's explicit zeros on the diagonal contribute nothing and are
/// left out) and B20 (2→0) for both; no_sequential also A101 (1→1), A232 (2→2, faces sharing a
/// contact), B01/B10, B14/B41, B03/B30 (the 6 nodes of a contact), B13/B31 (its 6 edges), B21,
/// and the signed incidence as values, B23signed (2→3) and B32signed (3→2): −1 face0, +1 face1.
/// With virtual object nodes, rank 0 and 1 hold N+O and E+N cells; virtual nodes and spokes
/// are in no face, and B04/B40 list mesh nodes only (the reference's empty virtual rows).
inline std::map<std::string, Neighborhood> hopnet_neighborhoods(const HopnetGeometry& g,
                                                                const HopnetFrame& f) {
  const std::int64_t N = g.num_nodes(), E = g.num_edges(), O = g.num_objects(), F = f.num_faces(),
                     C = f.num_contacts();
  const std::int64_t N0 = g.num_rank0(), E1 = g.num_rank1();
  const Architecture arch = g.lifting.architecture;
  std::map<std::string, Neighborhood> out;
  const auto make = [&](const char* name, int sr, int tr, std::int64_t ns,
                        std::int64_t nt) -> Neighborhood& {
    auto& n = out[name];
    n.name = name;
    n.source_rank = sr;
    n.target_rank = tr;
    n.num_source = ns;
    n.num_target = nt;
    return n;
  };
  const auto link = [](Neighborhood& n, std::int64_t s, std::int64_t t) {
    n.source.push_back(s), n.target.push_back(t);
  };
  auto& b04 = make("B04", 0, 4, N0, O);
  auto& b40 = make("B40", 4, 0, O, N0);
  for (std::int64_t n = 0; n < N; ++n) {
    const auto o = g.node_object[static_cast<std::size_t>(n)];
    link(b04, n, o), link(b40, o, n);
  }
  auto& b02 = make("B02", 0, 2, N0, F);
  auto& b12 = make("B12", 1, 2, E1, F);
  auto& b42 = make("B42", 4, 2, O, F);
  auto& b24 = make("B24", 2, 4, F, O);
  for (std::int64_t r = 0; r < F; ++r) {
    const auto gf = f.faces[static_cast<std::size_t>(r)];
    for (int k = 0; k < 3; ++k)
      link(b02, g.face_nodes(gf, k), r), link(b12, g.face_edges(gf, k), r);
    const auto o = g.node_object[static_cast<std::size_t>(g.face_nodes(gf, 0))];
    link(b42, o, r), link(b24, r, o);
  }
  auto& neg = make("B23neg", 2, 3, F, C);
  auto& pos = make("B23pos", 2, 3, F, C);
  auto& b32 = make("B32", 3, 2, C, F);
  // Reference: a face's message into each half is computed once per contact in which the face has
  // that role and written with index_put_, so its gradient comes back that many times (k_neg,
  // k_pos): the backward values. Native mode keeps the true gradient.
  std::vector<std::int64_t> k_neg(static_cast<std::size_t>(F), 0),
      k_pos(static_cast<std::size_t>(F), 0);
  for (const auto& c : f.contacts)
    ++k_neg[static_cast<std::size_t>(c[0])], ++k_pos[static_cast<std::size_t>(c[1])];
  const bool mixed = g.mode == FeatureMode::reference;
  for (std::int64_t c = 0; c < C; ++c) {
    for (int k = 0; k < 2; ++k) {
      const auto face = f.contacts[static_cast<std::size_t>(c)][static_cast<std::size_t>(k)];
      const auto kn = static_cast<double>(k_neg[static_cast<std::size_t>(face)]),
                 kp = static_cast<double>(k_pos[static_cast<std::size_t>(face)]);
      const double role_neg = k == 0, role_pos = k == 1;
      neg.source.push_back(face), neg.target.push_back(c),
          neg.values.push_back(mixed ? (kn > 0) : role_neg);
      pos.source.push_back(face), pos.target.push_back(c),
          pos.values.push_back(mixed ? (kp > 0) : role_pos);
      if (mixed) neg.backward_values.push_back(kn), pos.backward_values.push_back(kp);
      b32.source.push_back(c), b32.target.push_back(face),
          b32.roles.push_back(static_cast<std::int8_t>(k == 0 ? -1 : 1));
    }
  }
  if (arch == Architecture::hopnet) return out;

  auto& a010 = make("A010", 0, 0, N0, N0);
  for (std::int64_t e = 0; e < E; ++e) {
    const auto [s, d] = g.edges[static_cast<std::size_t>(e)];
    link(a010, s, d), link(a010, d, s);
  }
  if (arch == Architecture::no_object_cells)
    for (std::int64_t n = 0; n < N; ++n)
      link(a010, n, N + g.node_object[static_cast<std::size_t>(n)]),
          link(a010, N + g.node_object[static_cast<std::size_t>(n)], n);
  auto& b20 = make("B20", 2, 0, F, N0);
  for (std::size_t k = 0; k < b02.source.size(); ++k) link(b20, b02.target[k], b02.source[k]);
  if (arch != Architecture::no_sequential) return out;

  auto& b01 = make("B01", 0, 1, N, E);
  auto& b10 = make("B10", 1, 0, E, N);
  auto& b14 = make("B14", 1, 4, E, O);
  auto& b41 = make("B41", 4, 1, O, E);
  std::vector<std::vector<std::int64_t>> node_edges(static_cast<std::size_t>(N));
  for (std::int64_t e = 0; e < E; ++e) {
    for (auto n : g.edges[static_cast<std::size_t>(e)])
      link(b01, n, e), link(b10, e, n), node_edges[static_cast<std::size_t>(n)].push_back(e);
    const auto o = g.node_object[static_cast<std::size_t>(g.edges[static_cast<std::size_t>(e)][0])];
    link(b14, e, o), link(b41, o, e);
  }
  auto& a101 = make("A101", 1, 1, E, E);
  for (const auto& es : node_edges)
    for (auto a : es)
      for (auto b : es)
        if (a != b) link(a101, a, b);
  auto& b21 = make("B21", 2, 1, F, E);
  for (std::size_t k = 0; k < b12.source.size(); ++k) link(b21, b12.target[k], b12.source[k]);
  auto& a232 = make("A232", 2, 2, F, F);
  std::set<std::pair<std::int64_t, std::int64_t>> faces_in_contact;  // adjacency is 0/1
  for (const auto& c : f.contacts)
    if (c[0] != c[1]) faces_in_contact.insert({c[0], c[1]}), faces_in_contact.insert({c[1], c[0]});
  for (const auto& [a, b] : faces_in_contact) link(a232, a, b);
  auto& b03 = make("B03", 0, 3, N, C);
  auto& b30 = make("B30", 3, 0, C, N);
  auto& b13 = make("B13", 1, 3, E, C);
  auto& b31 = make("B31", 3, 1, C, E);
  auto& b23 = make("B23signed", 2, 3, F, C);
  auto& b32s = make("B32signed", 3, 2, C, F);
  for (std::int64_t c = 0; c < C; ++c)
    for (int k = 0; k < 2; ++k) {
      const auto face = f.contacts[static_cast<std::size_t>(c)][static_cast<std::size_t>(k)];
      const auto gf = f.faces[static_cast<std::size_t>(face)];
      for (int v = 0; v < 3; ++v)
        link(b03, g.face_nodes(gf, v), c), link(b30, c, g.face_nodes(gf, v)),
            link(b13, g.face_edges(gf, v), c), link(b31, c, g.face_edges(gf, v));
      link(b23, face, c), link(b32s, c, face);
      b23.values.push_back(k == 0 ? -1.0 : 1.0), b32s.values.push_back(k == 0 ? -1.0 : 1.0);
    }
  return out;
}

}  // namespace topos::models::hopnet
