// topos/data/tdl_case-inl.hpp
// The implementation of tdl_case.hpp (documented there): compiled once into topos::data
// (src/tdl_case.cpp), or inline with TOPOS_HEADER_ONLY (topos/config.hpp). Evaluating an
// operator instantiates every operator of every domain and Eigen's sparse and dense algebra,
// which takes minutes in each translation unit that compiles it. The helpers in detail are this
// file's own.
#pragma once

#include "topos/data/tdl_case.hpp"

#include "topos/core/normalization.hpp"
#include "topos/core/operators.hpp"
#include "topos/core/spectral.hpp"

#include <cmath>
#include <limits>
#include <unordered_map>

namespace topos::data {

namespace detail {

using json = nlohmann::ordered_json;

struct NodeMap {
  std::unordered_map<std::int64_t, std::int64_t> id;
  std::string source;
  std::int64_t operator()(const json& label, const std::string& where) const {
    if (!data::is_int64(label))
      throw data::DataError(source + ": " + where + ": node " + label.dump() +
                            " is not an integer");
    auto it = id.find(label.get<std::int64_t>());
    if (it == id.end())
      throw data::DataError(source + ": " + where + ": node " + label.dump() +
                            " is not one of the listed nodes");
    return it->second;
  }
  std::vector<std::int64_t> cell(const json& c, const std::string& where) const {
    if (!c.is_array())
      throw data::DataError(source + ": " + where + ": a cell must be a list of nodes, got " +
                            c.dump());
    std::vector<std::int64_t> out;
    for (const auto& v : c) out.push_back((*this)(v, where));
    return out;
  }
};

// Nodes are numbered by their position in the list; labels must be distinct integers, and
// increasing where orientation follows the node order (simplicial).
inline NodeMap map_nodes(const json& labels, const std::string& source, bool increasing) {
  NodeMap m;
  m.source = source;
  if (!labels.is_array()) throw data::DataError(source + ": the node list must be an array");
  std::int64_t previous = 0;
  for (std::size_t i = 0; i < labels.size(); ++i) {
    const json& l = labels[i].is_array() && labels[i].size() == 1 ? labels[i][0] : labels[i];
    if (!data::is_int64(l))
      throw data::DataError(source + ": node " + labels[i].dump() +
                            " is not an integer (or a one-node cell)");
    const auto v = l.get<std::int64_t>();
    if (!m.id.emplace(v, static_cast<std::int64_t>(i)).second)
      throw data::DataError(source + ": node " + std::to_string(v) + " is listed twice");
    if (increasing && i > 0 && v <= previous) {
      throw data::DataError(source +
                            ": nodes must be listed in increasing order (simplex orientation is "
                            "the sorted node order); " +
                            std::to_string(v) + " follows " + std::to_string(previous));
    }
    previous = v;
  }
  return m;
}

inline const json& member(const json& j, const char* key, const std::string& source) {
  if (!j.is_object() || !j.contains(key))
    throw data::DataError(source + ": missing \"" + key + "\"");
  return j.at(key);
}

// Ranks of a {"0": [...], "1": [...]} object, checked contiguous from 0.
inline std::vector<const json*> ranked_cells(const json& cells, const std::string& source) {
  if (!cells.is_object())
    throw data::DataError(source + ": \"cells\" must be an object {rank: [cells...]}");
  std::map<int, const json*> by_rank;
  for (auto it = cells.begin(); it != cells.end(); ++it) {
    // Digits only, no leading zero: std::stoi would take " 2", "+2" or "02" for rank 2.
    int r = -1;
    const std::string& key = it.key();
    if (!key.empty() && key.size() <= 9 && (key == "0" || key[0] != '0') &&
        key.find_first_not_of("0123456789") == std::string::npos)
      r = std::stoi(key);
    if (r < 0)
      throw data::DataError(source + ": cell rank \"" + it.key() +
                            "\" is not a non-negative integer");
    if (!it.value().is_array())
      throw data::DataError(source + ": cells of rank " + it.key() + " must be a list");
    by_rank[r] = &it.value();
  }
  std::vector<const json*> out;
  for (auto& [r, p] : by_rank) {
    if (r != static_cast<int>(out.size()))
      throw data::DataError(source + ": cell ranks must run 0, 1, 2, ... without gaps; rank " +
                            std::to_string(out.size()) + " is missing");
    out.push_back(p);
  }
  if (out.empty()) throw data::DataError(source + ": no cells (rank 0, the nodes, is required)");
  return out;
}

}  // namespace detail

TOPOS_INLINE Domain parse_domain(const nlohmann::ordered_json& j, const std::string& src,
                                 const std::string& fallback_domain) {
  using detail::json;
  std::string kind = fallback_domain;
  if (j.is_object() && j.contains("domain")) {
    if (!j["domain"].is_string()) throw data::DataError(src + ": \"domain\" must be a string");
    kind = j["domain"].get<std::string>();
  }
  if (kind.empty())
    throw data::DataError(src + ": no \"domain\" (simplicial, cell, combinatorial or hypergraph)");
  try {
    if (kind == "simplicial") {
      const auto ranks = detail::ranked_cells(detail::member(j, "cells", src), src);
      const detail::NodeMap nodes = detail::map_nodes(*ranks[0], src, true);
      std::vector<std::vector<std::vector<std::int64_t>>> cells(ranks.size());
      for (std::int64_t v = 0; v < static_cast<std::int64_t>(ranks[0]->size()); ++v)
        cells[0].push_back({v});
      for (std::size_t k = 1; k < ranks.size(); ++k)
        for (std::size_t i = 0; i < ranks[k]->size(); ++i)
          cells[k].push_back(nodes.cell(
              (*ranks[k])[i], "rank " + std::to_string(k) + " cell " + std::to_string(i)));
      return SimplicialComplex::from_ordered(cells);
    }
    if (kind == "cell") {
      const detail::NodeMap nodes = detail::map_nodes(detail::member(j, "nodes", src), src, false);
      std::vector<CellComplex::Edge> edges;
      const json& je = detail::member(j, "edges", src);
      if (!je.is_array()) throw data::DataError(src + ": \"edges\" must be a list");
      for (std::size_t i = 0; i < je.size(); ++i) {
        const auto e = nodes.cell(je[i], "edge " + std::to_string(i));
        if (e.size() != 2)
          throw data::DataError(src + ": edge " + std::to_string(i) + " " + je[i].dump() +
                                " must have exactly 2 nodes");
        edges.push_back({e[0], e[1]});
      }
      std::vector<std::vector<std::int64_t>> cells;
      const json& jc = j.contains("cells") ? j["cells"] : json::array();
      if (!jc.is_array())
        throw data::DataError(src + ": \"cells\" must be a list of vertex cycles");
      for (std::size_t i = 0; i < jc.size(); ++i)
        cells.push_back(nodes.cell(jc[i], "2-cell " + std::to_string(i)));
      return CellComplex::from_ordered(static_cast<std::int64_t>(nodes.id.size()), edges, cells);
    }
    if (kind == "combinatorial") {
      const auto ranks = detail::ranked_cells(detail::member(j, "cells", src), src);
      const detail::NodeMap nodes = detail::map_nodes(*ranks[0], src, false);
      CombinatorialComplex<> cc(static_cast<std::int64_t>(ranks[0]->size()));
      for (std::size_t k = 1; k < ranks.size(); ++k) {
        for (std::size_t i = 0; i < ranks[k]->size(); ++i) {
          const std::string where = "rank " + std::to_string(k) + " cell " + std::to_string(i);
          const auto [id, inserted] =
              cc.add_cell(nodes.cell((*ranks[k])[i], where), static_cast<int>(k));
          if (!inserted)
            throw data::DataError(src + ": " + where + " " + (*ranks[k])[i].dump() +
                                  " repeats cell " + std::to_string(id) + " of the same rank");
        }
      }
      return cc;
    }
    if (kind == "hypergraph") {
      const detail::NodeMap nodes = detail::map_nodes(detail::member(j, "nodes", src), src, false);
      Hypergraph h(static_cast<std::int64_t>(nodes.id.size()));
      const json& jh = detail::member(j, "hyperedges", src);
      if (!jh.is_array()) throw data::DataError(src + ": \"hyperedges\" must be a list");
      for (std::size_t i = 0; i < jh.size(); ++i)
        h.add_hyperedge(nodes.cell(jh[i], "hyperedge " + std::to_string(i)));
      return h;
    }
  } catch (const ComplexError& e) {
    throw data::DataError(src + ": " + e.what());
  }
  throw data::DataError(src + ": unknown domain \"" + kind +
                        "\" (expected simplicial, cell, combinatorial or hypergraph)");
}

TOPOS_INLINE Domain read_domain(const std::filesystem::path& complex_json,
                                const std::string& fallback_domain) {
  return parse_domain(data::read_ordered_json_file(complex_json), complex_json.string(),
                      fallback_domain);
}

namespace detail {

// One operator's evaluation context: its name and op for error messages, typed argument access.
struct OpCall {
  const std::string& name;
  const std::string& op;
  const json& args;
  const Operators& earlier;

  [[noreturn]] void fail(const std::string& why) const {
    throw data::DataError("operator '" + name + "' (op " + op + "): " + why);
  }
  bool has(const char* k) const {
    return args.is_object() && args.contains(k) && !args[k].is_null();
  }
  const json& arg(const char* k) const {
    if (!has(k)) fail(std::string("missing argument '") + k + "'");
    return args[k];
  }
  int integer(const char* k) const {
    const json& v = arg(k);
    if (!data::is_int64(v) || v.get<std::int64_t>() < std::numeric_limits<int>::min() ||
        v.get<std::int64_t>() > std::numeric_limits<int>::max())
      fail(std::string("argument '") + k + "' must be an integer, got " + v.dump());
    return static_cast<int>(v.get<std::int64_t>());
  }
  double number(const char* k) const {
    const json& v = arg(k);
    if (!v.is_number()) fail(std::string("argument '") + k + "' must be a number, got " + v.dump());
    return v.get<double>();
  }
  bool boolean(const char* k, bool dflt) const {
    if (!has(k)) return dflt;
    if (!args[k].is_boolean())
      fail(std::string("argument '") + k + "' must be true or false, got " + args[k].dump());
    return args[k].get<bool>();
  }
  const SparseOp& ref(const json& v, const char* k) const {
    if (!v.is_string())
      fail(std::string("argument '") + k + "' must name an earlier operator, got " + v.dump());
    auto it = earlier.by_name.find(v.get<std::string>());
    if (it == earlier.by_name.end())
      fail(std::string("argument '") + k + "' names '" + v.get<std::string>() +
           "', which is not an earlier operator of this case");
    return it->second;
  }
  const SparseOp& ref(const char* k) const { return ref(arg(k), k); }
};

template <class D>
SparseOp oriented_operator(const D& d, const OpCall& c) {
  const std::string& op = c.op;
  if (op == "incidence_matrix") {
    if (c.has("to_rank")) return d.inclusion_matrix(c.integer("rank"), c.integer("to_rank"));
    return d.incidence_matrix(c.integer("rank"), Signed(c.boolean("signed", true)));
  }
  if (op == "coincidence_matrix")
    return d.coincidence_matrix(c.integer("rank"), Signed(c.boolean("signed", true)));
  if (op == "hodge_laplacian_matrix")
    return d.hodge_laplacian_matrix(c.integer("rank"), c.boolean("signed", true));
  if (op == "up_laplacian_matrix")
    return d.up_laplacian_matrix(c.integer("rank"), c.boolean("signed", true));
  if (op == "down_laplacian_matrix")
    return d.down_laplacian_matrix(c.integer("rank"), c.boolean("signed", true));
  if (op == "adjacency_matrix") {
    if (c.has("via_rank")) return d.adjacency_matrix_via(c.integer("rank"), c.integer("via_rank"));
    return d.adjacency_matrix(c.integer("rank"), Signed(c.boolean("signed", false)));
  }
  if (op == "coadjacency_matrix") {
    if (c.has("via_rank"))
      return d.coadjacency_matrix_via(c.integer("rank"), c.integer("via_rank"));
    return d.coadjacency_matrix(c.integer("rank"), Signed(c.boolean("signed", false)));
  }
  if (op == "normalized_laplacian_matrix") return d.normalized_laplacian_matrix(c.integer("rank"));
  c.fail("unknown op");
}

template <class D>
SparseOp set_operator(const D& d, const OpCall& c) {
  const std::string& op = c.op;
  if (op == "incidence_matrix") return d.incidence_matrix(c.integer("rank"), c.integer("to_rank"));
  if (op == "adjacency_matrix") return d.adjacency_matrix(c.integer("rank"), c.integer("via_rank"));
  if (op == "coadjacency_matrix")
    return d.coadjacency_matrix(c.integer("rank"), c.integer("via_rank"));
  c.fail("unknown op");
}

inline bool is_complex_op(const std::string& op) {
  static const char* ops[] = {"incidence_matrix",       "coincidence_matrix",
                              "hodge_laplacian_matrix", "up_laplacian_matrix",
                              "down_laplacian_matrix",  "adjacency_matrix",
                              "coadjacency_matrix",     "normalized_laplacian_matrix"};
  for (const char* o : ops)
    if (op == o) return true;
  return false;
}

}  // namespace detail

TOPOS_INLINE std::vector<std::string> known_ops() {
  return {"incidence_matrix",
          "coincidence_matrix",
          "hodge_laplacian_matrix",
          "up_laplacian_matrix",
          "down_laplacian_matrix",
          "adjacency_matrix",
          "coadjacency_matrix",
          "normalized_laplacian_matrix",
          "compute_laplacian_normalized_matrix",
          "compute_x_laplacian_normalized_matrix",
          "compute_kipf_adjacency_normalized_matrix",
          "compute_xu_asymmetric_normalized_matrix",
          "compute_bunch_normalized_matrices",
          "transpose",
          "abs",
          "sum",
          "scale",
          "identity",
          "pinv"};
}

TOPOS_INLINE SparseOp evaluate_operator(const std::string& name, const std::string& op,
                                        const nlohmann::ordered_json& args, const Domain& domain,
                                        const Operators& earlier) {
  const detail::OpCall c{name, op, args, earlier};
  try {
    if (detail::is_complex_op(op)) {
      return std::visit(
          [&](const auto& d) -> SparseOp {
            using D = std::decay_t<decltype(d)>;
            if constexpr (std::is_same_v<D, SimplicialComplex> || std::is_same_v<D, CellComplex>) {
              return detail::oriented_operator(d, c);
            } else {
              if (op != "incidence_matrix" && op != "adjacency_matrix" &&
                  op != "coadjacency_matrix") {
                c.fail(std::string("not defined on a ") + domain_name(domain) +
                       " domain (it has incidence_matrix, adjacency_matrix and coadjacency_matrix "
                       "between ranks)");
              }
              return detail::set_operator(d, c);
            }
          },
          domain);
    }
    if (op == "compute_laplacian_normalized_matrix")
      return compute_laplacian_normalized_matrix(c.ref("L"));
    if (op == "compute_x_laplacian_normalized_matrix")
      return compute_x_laplacian_normalized_matrix(c.ref("L"), c.ref("L_x"));
    if (op == "compute_kipf_adjacency_normalized_matrix") {
      return compute_kipf_adjacency_normalized_matrix(
          c.ref("A"), c.boolean("add_identity", false),
          c.has("identity_multiplier") ? c.number("identity_multiplier") : 1.0);
    }
    if (op == "compute_xu_asymmetric_normalized_matrix")
      return compute_xu_asymmetric_normalized_matrix(c.ref("B"), c.boolean("is_sparse", true));
    if (op == "compute_bunch_normalized_matrices") {
      const int k = c.integer("output");
      if (k < 0 || k > 3)
        c.fail("argument 'output' must be 0..3 (B1N, B1TN, B2N, B2TN), got " + std::to_string(k));
      return compute_bunch_normalized_matrices(c.ref("B1"),
                                               c.ref("B2"))[static_cast<std::size_t>(k)];
    }
    if (op == "transpose") return sparse::transpose(c.ref("of"));
    if (op == "abs") return sparse::abs(c.ref("of"));
    if (op == "scale") return sparse::pruned(SparseOp(c.ref("of") * c.number("factor")));
    if (op == "pinv") {
      // Dense SVD: bounded, so that a case cannot ask for gigabytes and hours.
      const SparseOp& of = c.ref("of");
      if (static_cast<double>(of.rows()) * static_cast<double>(of.cols()) > kMaxPinvEntries) {
        c.fail("'" + c.args["of"].get<std::string>() + "' is " + std::to_string(of.rows()) + "x" +
               std::to_string(of.cols()) + "; pinv is dense and limited to " +
               std::to_string(kMaxPinvEntries) + " entries");
      }
      return sparse::from_dense(pinv(Eigen::MatrixXd(of)));
    }
    if (op == "sum") {
      const auto& of = c.arg("of");
      if (!of.is_array() || of.empty())
        c.fail("argument 'of' must be a non-empty list of earlier operators");
      SparseOp s = c.ref(of[0], "of");
      for (std::size_t i = 1; i < of.size(); ++i) {
        const SparseOp& t = c.ref(of[i], "of");
        if (t.rows() != s.rows() || t.cols() != s.cols()) {
          c.fail("cannot add " + of[i].dump() + " (" + std::to_string(t.rows()) + "x" +
                 std::to_string(t.cols()) + ") to a " + std::to_string(s.rows()) + "x" +
                 std::to_string(s.cols()) + " sum");
        }
        s = sparse::add(s, t);
      }
      return s;
    }
    if (op == "identity") {
      const SparseOp& of = c.ref("size_of");
      const int axis = c.has("axis") ? c.integer("axis") : 0;
      if (axis != 0 && axis != 1)
        c.fail("argument 'axis' must be 0 or 1, got " + std::to_string(axis));
      return sparse::identity(axis == 0 ? of.rows() : of.cols());
    }
  } catch (const ComplexError& e) {
    c.fail(e.what());
  }
  std::string list;
  for (const auto& k : known_ops()) list += (list.empty() ? "" : ", ") + k;
  c.fail("unknown op (known: " + list + ")");
}

TOPOS_INLINE Operators compute_operators(const nlohmann::ordered_json& ops, const Domain& domain,
                                         const std::string& source) {
  if (!ops.is_object())
    throw data::DataError(source + ": must be an object {name: {\"op\", \"args\"}}");
  Operators out;
  for (auto it = ops.begin(); it != ops.end(); ++it) {
    const std::string& name = it.key();
    const auto& spec = it.value();
    if (!spec.is_object() || !spec.contains("op") || !spec["op"].is_string())
      throw data::DataError(source + ": operator '" + name + "' has no \"op\" string");
    static const nlohmann::ordered_json no_args = nlohmann::ordered_json::object();
    const auto& args = spec.contains("args") ? spec["args"] : no_args;
    if (out.by_name.count(name))
      throw data::DataError(source + ": operator '" + name + "' is defined twice");
    const std::string& op = spec["op"].get<std::string>();
    SparseOp m;
    try {
      m = evaluate_operator(name, op, args, domain, out);
    } catch (const data::DataError& e) {
      throw data::DataError(source + ": " + e.what());  // the file, then the operator
    }
    // Overflow (a huge scale factor or identity multiplier) or a negative degree under a square
    // root: an error, not NaN or inf handed to a model.
    for (Eigen::Index i = 0; i < m.outerSize(); ++i) {
      for (SparseOp::InnerIterator it(m, i); it; ++it) {
        if (!std::isfinite(it.value())) {
          throw data::DataError(source + ": operator '" + name + "' (op " + op + ") has entry (" +
                                std::to_string(it.row()) + ", " + std::to_string(it.col()) +
                                ") = " + std::to_string(it.value()) + ", not a finite number");
        }
      }
    }
    out.by_name.emplace(name, std::move(m));
    out.order.push_back(name);
  }
  return out;
}

TOPOS_INLINE Operators compute_operators(const std::filesystem::path& case_dir) {
  std::string fallback;
  if (std::filesystem::exists(case_dir / "case.json"))
    fallback = case_domain(data::read_json_file(case_dir / "case.json"));
  const Domain domain = read_domain(case_dir / "complex.json", fallback);
  return compute_operators(data::read_ordered_json_file(case_dir / "operators.json"), domain,
                           (case_dir / "operators.json").string());
}

}  // namespace topos::data
