// topos/models/topobench/lifting-inl.hpp
// lift_graph's implementation (topos/models/topobench/lifting.hpp declares it), compiled once into
// topos::topobench (src/topobench.cpp), or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/core/domain_lifting.hpp"
#include "topos/core/sparse_matrix.hpp"
#include "topos/models/topobench/lifting.hpp"

#include <algorithm>
#include <cmath>
#include <functional>

namespace topos::models::topobench {

/// A sparse matrix as Triplets (its zeros as float dropped).
inline Triplets to_triplets(const SparseMatrix& m) {
  Triplets t;
  t.rows = m.rows(), t.cols = m.cols();
  t.row.reserve(static_cast<std::size_t>(m.nonZeros()));
  t.col.reserve(t.row.capacity()), t.value.reserve(t.row.capacity());
  for (Eigen::Index i = 0; i < m.outerSize(); ++i)
    for (SparseMatrix::InnerIterator it(m, i); it; ++it)
      if (static_cast<float>(it.value()) != 0.0f)
        t.row.push_back(it.row()), t.col.push_back(it.col()),
            t.value.push_back(static_cast<float>(it.value()));
  return t;
}

namespace detail {

inline Eigen::VectorXd inverse_sqrt(Eigen::VectorXd d) {
  for (Eigen::Index i = 0; i < d.size(); ++i) d[i] = d[i] > 0 ? 1.0 / std::sqrt(d[i]) : 0.0;
  return d;
}
/// |B|ᵀ x for row-major x (rows = B's rows, `width` columns).
inline std::vector<float> project_sum(const SparseMatrix& b, const std::vector<float>& x,
                                      std::int64_t width) {
  std::vector<float> y(static_cast<std::size_t>(b.cols() * width), 0.0f);
  for (Eigen::Index i = 0; i < b.outerSize(); ++i)
    for (SparseMatrix::InnerIterator it(b, i); it; ++it) {
      const float w = static_cast<float>(std::abs(it.value()));
      const float* src = x.data() + it.row() * width;
      float* dst = y.data() + it.col() * width;
      for (std::int64_t c = 0; c < width; ++c) dst[c] += w * src[c];
    }
  return y;
}
/// The incidence of rank k of a complex with fewer ranks: an empty n_{k-1} × 0 matrix.
template <class Complex>
SparseMatrix incidence_or_empty(const Complex& c, int k, bool signed_) {
  if (k <= c.dim()) return c.incidence_matrix(k, Signed(signed_));
  return SparseMatrix(c.num_cells(k - 1), 0);
}
inline SparseMatrix gram(const SparseMatrix& a, const SparseMatrix& b) {  // a · b
  return sparse::multiply(a, b);
}
inline std::vector<float> to_floats(const Eigen::VectorXd& d) {
  std::vector<float> f(static_cast<std::size_t>(d.size()));
  for (Eigen::Index i = 0; i < d.size(); ++i)
    f[static_cast<std::size_t>(i)] = static_cast<float>(d[i]);
  return f;
}
/// Σ_k a_k b_k kept as factors, scaled by diag(d) on both sides when d is given.
inline FactoredTriplets factored(const sparse::ProductTerms& terms,
                                 const Eigen::VectorXd* d = nullptr) {
  FactoredTriplets f;
  f.rows = terms.at(0).first->rows(), f.cols = terms.at(0).second->cols();
  for (const auto& [a, b] : terms) f.products.push_back({to_triplets(*a), to_triplets(*b)});
  if (d) f.left = f.right = to_floats(*d);
  return f;
}

/// TopoTune's neighbourhood `name` (topobench/routes.hpp) from the signed incidences b[1..3] (a
/// cell complex's B_3 empty): target × source, every value 1.
inline Triplets neighborhood(const std::vector<SparseMatrix>& b, const std::string& name,
                             int max_rank) {
  using Kind = NeighborhoodRoute::Kind;
  const NeighborhoodRoute r = neighborhood_route(name);
  const int lo = r.up ? r.rank : r.rank - r.hops, hi = r.up ? r.rank + r.hops : r.rank;
  if (std::max(r.source_rank(), r.target_rank()) > max_rank || hi > 3)
    throw std::invalid_argument("lift_graph: neighbourhood '" + name + "' reaches rank " +
                                std::to_string(std::max(r.target_rank(), hi)) +
                                ", above the lifted ranks (cells of 0.." +
                                std::to_string(max_rank) + ", incidences up to B_3)");
  // M = |B_{lo+1}| ⋯ |B_hi|: rank lo × rank hi, the cells of rank hi above each cell of rank lo.
  SparseMatrix m = sparse::abs(b[static_cast<std::size_t>(lo + 1)]);
  for (int k = lo + 2; k <= hi; ++k)
    m = sparse::multiply(m, sparse::abs(b[static_cast<std::size_t>(k)]));
  const SparseMatrix mt = sparse::transpose(m);
  SparseMatrix out;
  if (r.kind == Kind::incidence)
    out = r.up ? mt : m;
  else {
    out = r.up ? sparse::multiply(m, mt) : sparse::multiply(mt, m);
    if (r.kind == Kind::adjacency) out = sparse::without_diagonal(out);
  }
  Triplets t = to_triplets(out);
  std::fill(t.value.begin(), t.value.end(), 1.0f);
  return t;
}

}  // namespace detail

/// Lifts one graph (nodes 0..n-1, undirected edges u < v, unique) with node features `x`
/// (row-major, `num_features` columns) and optional per-edge labels (aligned with `edges`).
TOPOS_INLINE LiftedGraph lift_graph(std::int64_t num_nodes,
                                    const std::vector<std::array<std::int64_t, 2>>& edges,
                                    const std::vector<float>& x, std::int64_t num_features,
                                    const std::vector<std::int64_t>& edge_labels, Domain domain,
                                    const GraphLiftingOptions& o) {
  if (static_cast<std::int64_t>(x.size()) != num_nodes * num_features)
    throw std::invalid_argument("lift_graph: " + std::to_string(x.size()) + " feature values for " +
                                std::to_string(num_nodes) + " nodes × " +
                                std::to_string(num_features));
  LiftedGraph g;
  g.sizes.push_back(num_nodes);
  g.widths.push_back(num_features);
  g.x.push_back(x);
  auto& ops = g.operators;
  using namespace topos::sparse;
  // Adds operator `name` when it is wanted, computing it only then.
  const auto wanted = [&](const std::string& name) {
    return o.operators.empty() || o.operators.count(name);
  };
  const auto put = [&](const char* name, const std::function<Triplets()>& make) {
    if (wanted(name) && !o.factored.count(name)) ops[name] = make();
  };
  const auto put_factored = [&](const char* name, const std::function<FactoredTriplets()>& make) {
    if (wanted(name) && o.factored.count(name)) g.factored[name] = make();
  };
  for (const auto& name : o.factored)
    if (!factorable_operators(domain, o.signed_incidence).count(name))
      throw std::invalid_argument("lift_graph: operator '" + name +
                                  "' cannot be kept as factors in the " + domain_name(domain) +
                                  " domain" +
                                  (o.signed_incidence ? "" : " without signed incidences"));
  for (const auto& name : o.operators)
    if (is_neighborhood_name(name)) {
      neighborhood_route(name);  // a malformed name is an error here, listing the valid forms
      if (domain == Domain::graph || domain == Domain::hypergraph)
        throw std::invalid_argument("lift_graph: neighbourhood '" + name +
                                    "' needs the cell or simplicial domain, not the " +
                                    domain_name(domain) + " one");
    }
  if (domain == Domain::graph) {
    // Â = D̂^-1/2 (A + I) D̂^-1/2, D̂ the degrees plus one (the self-loop GCNConv adds).
    std::vector<Eigen::Triplet<double, std::int64_t>> t;
    for (const auto& e : edges) t.emplace_back(e[0], e[1], 1.0), t.emplace_back(e[1], e[0], 1.0);
    for (std::int64_t v = 0; v < num_nodes; ++v) t.emplace_back(v, v, 1.0);
    const SparseMatrix a = from_triplets(num_nodes, num_nodes, t);
    const Eigen::VectorXd d = detail::inverse_sqrt(row_sums(a));
    put("gcn_adjacency", [&] { return to_triplets(scale(a, d, d)); });
    return g;
  }
  if (domain == Domain::hypergraph) {
    const Hypergraph h = khop_lifting(num_nodes, edges, o.khop);
    const SparseMatrix inc = h.incidence_matrix(0, 1);  // nodes × hyperedges
    const Eigen::VectorXd dv = row_sums(inc);
    Eigen::VectorXd de = Eigen::VectorXd::Zero(inc.cols()), size = de;
    for (Eigen::Index i = 0; i < inc.outerSize(); ++i)
      for (SparseMatrix::InnerIterator it(inc, i); it; ++it)
        de[it.col()] += dv[it.row()] * it.value(), size[it.col()] += it.value();
    for (Eigen::Index e = 0; e < de.size(); ++e) de[e] = size[e] > 0 ? de[e] / size[e] : 0.0;
    put("incidence_1", [&] { return to_triplets(inc); });
    put("incidence_1_norm", [&] {
      return to_triplets(scale(inc, detail::inverse_sqrt(dv), detail::inverse_sqrt(de)));
    });
    put("node_degree", [&] { return to_triplets(scale(identity(num_nodes), dv, {})); });
    g.sizes.push_back(inc.cols());
    g.widths.push_back(num_features);
    g.x.push_back(detail::project_sum(inc, x, num_features));
    return g;
  }
  // Cell and simplicial complexes: B_1, B_2 (and B_3 for the simplicial L_2), the features.
  std::vector<SparseMatrix> b(4);  // b[k] = B_k signed, k = 1..3
  std::vector<std::array<std::int64_t, 2>> complex_edges;
  if (domain == Domain::cell) {
    const CellComplex cc = cycle_lifting(num_nodes, edges, o.max_cell_length);
    for (int k = 1; k <= 2; ++k)
      b[static_cast<std::size_t>(k)] = detail::incidence_or_empty(cc, k, true);
    b[3] = SparseMatrix(b[2].cols(), 0);  // no 3-cells
    for (std::int64_t e = 0; e < cc.num_edges(); ++e) complex_edges.push_back(cc.edge(e));
  } else {
    const SimplicialComplex sc = clique_lifting(num_nodes, edges, o.complex_dim);
    for (int k = 1; k <= 3; ++k)
      b[static_cast<std::size_t>(k)] = detail::incidence_or_empty(sc, k, true);
    for (std::int64_t e = 0; e < sc.num_cells(1); ++e)
      complex_edges.push_back({sc.data(1, e)[0], sc.data(1, e)[1]});
  }
  for (int k = 1; k <= o.max_rank; ++k) {
    const auto& bk = b[static_cast<std::size_t>(k)];
    g.sizes.push_back(bk.cols());
    if (k == 1 && o.edge_features) {
      // The edge labels one-hot, matched to the complex's edges by their nodes.
      if (edge_labels.size() != edges.size())
        throw std::invalid_argument("lift_graph: edge features asked for without edge labels");
      std::vector<float> x1(static_cast<std::size_t>(bk.cols() * o.num_edge_labels), 0.0f);
      for (std::size_t e = 0; e < complex_edges.size(); ++e) {
        std::array<std::int64_t, 2> key{std::min(complex_edges[e][0], complex_edges[e][1]),
                                        std::max(complex_edges[e][0], complex_edges[e][1])};
        const auto it = std::lower_bound(edges.begin(), edges.end(), key);
        if (it == edges.end() || *it != key)
          throw std::invalid_argument("lift_graph: the complex has an edge the graph has not");
        const auto label = edge_labels[static_cast<std::size_t>(it - edges.begin())];
        if (label < 0 || label >= o.num_edge_labels)
          throw std::invalid_argument("lift_graph: edge label " + std::to_string(label) +
                                      " outside [0, " + std::to_string(o.num_edge_labels) + ")");
        x1[e * static_cast<std::size_t>(o.num_edge_labels) + static_cast<std::size_t>(label)] =
            1.0f;
      }
      g.widths.push_back(o.num_edge_labels);
      g.x.push_back(std::move(x1));
    } else {
      g.widths.push_back(g.widths.back());
      g.x.push_back(detail::project_sum(bk, g.x.back(), g.widths.back()));
    }
  }
  const SparseMatrix &b1 = b[1], &b2 = b[2], &b3 = b[3];
  for (const auto& name : o.operators)
    if (is_neighborhood_name(name)) ops[name] = detail::neighborhood(b, name, o.max_rank);
  const SparseMatrix b1t = transpose(b1), b2t = transpose(b2), b3t = transpose(b3);
  if (domain == Domain::cell) {
    const SparseMatrix a1 = abs(b1), a2 = abs(b2), a1t = abs(b1t), a2t = abs(b2t);
    put("incidence_1", [&] { return to_triplets(a1); });
    put("incidence_2", [&] { return to_triplets(a2); });
    put("incidence_1_t", [&] { return to_triplets(a1t); });
    put("incidence_2_t", [&] { return to_triplets(a2t); });
    put("adjacency_0", [&] { return to_triplets(without_diagonal(detail::gram(a1, a1t))); });
    put("adjacency_1", [&] { return to_triplets(without_diagonal(detail::gram(a2, a2t))); });
    const auto down = [&] { return abs(detail::gram(b1t, b1)); };
    const auto up = [&] { return abs(detail::gram(b2, b2t)); };
    const auto gcn = [](const SparseMatrix& m) {
      const Eigen::VectorXd d = detail::inverse_sqrt(row_sums(m));
      return to_triplets(scale(m, d, d));
    };
    put("down_laplacian_1", [&] { return to_triplets(down()); });
    put("up_laplacian_1", [&] { return to_triplets(up()); });
    put("down_laplacian_1_gcn", [&] { return gcn(down()); });
    put("up_laplacian_1_gcn", [&] { return gcn(up()); });
    // |B_1ᵀB_1| = |B_1|ᵀ|B_1|: two distinct edges share at most one node. Its row sums are
    // |B_1|ᵀ (|B_1| 1): deg(u) + deg(v) for edge uv.
    put_factored("down_laplacian_1", [&] { return detail::factored({{&a1t, &a1}}); });
    put_factored("down_laplacian_1_gcn", [&] {
      const Eigen::VectorXd d =
          detail::inverse_sqrt(a1t * (a1 * Eigen::VectorXd::Ones(a1.cols())).eval());
      return detail::factored({{&a1t, &a1}}, &d);
    });
    return g;
  }
  const auto sign = [&](const SparseMatrix& m) { return o.signed_incidence ? m : abs(m); };
  // L_0 = B_1 B_1ᵀ; L_r = B_rᵀ B_r + B_{r+1} B_{r+1}ᵀ (zero blocks where a rank is empty).
  const auto down = [&](int r) { return r == 1 ? detail::gram(b1t, b1) : detail::gram(b2t, b2); };
  const auto up = [&](int r) {
    return r == 0 ? detail::gram(b1, b1t) : r == 1 ? detail::gram(b2, b2t) : detail::gram(b3, b3t);
  };
  const auto hodge = [&](int r) { return r == 0 ? up(0) : SparseMatrix(add(down(r), up(r))); };
  const auto norm = [&](const SparseMatrix& l) {
    const Eigen::VectorXd d = detail::inverse_sqrt(abs_row_sums(l));
    return to_triplets(scale(sign(l), d, d));
  };
  put("incidence_1", [&] { return to_triplets(sign(b1)); });
  put("incidence_2", [&] { return to_triplets(sign(b2)); });
  for (int r = 0; r <= 2; ++r) {
    const std::string R = std::to_string(r);
    put(("hodge_laplacian_" + R).c_str(), [&] { return to_triplets(sign(hodge(r))); });
    put(("hodge_laplacian_" + R + "_norm").c_str(), [&] { return norm(hodge(r)); });
    if (r == 0) continue;
    put(("down_laplacian_" + R).c_str(), [&] { return to_triplets(sign(down(r))); });
    put(("up_laplacian_" + R).c_str(), [&] { return to_triplets(sign(up(r))); });
  }
  // Signed only (factorable_operators): L_1's two products cancel where edges share a triangle.
  const sparse::ProductTerms l1{{&b1t, &b1}, {&b2, &b2t}};  // L_1 = B_1ᵀB_1 + B_2B_2ᵀ
  put_factored("down_laplacian_1", [&] { return detail::factored({l1[0]}); });
  put_factored("hodge_laplacian_1", [&] { return detail::factored(l1); });
  put_factored("hodge_laplacian_1_norm", [&] {
    const Eigen::VectorXd d = detail::inverse_sqrt(sparse::abs_row_sums_of_products(l1));
    return detail::factored(l1, &d);
  });
  return g;
}

}  // namespace topos::models::topobench
