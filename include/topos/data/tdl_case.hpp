// topos/data/tdl_case.hpp
// Reading a case of the TDL golden format (a folder with complex.json, operators.json and, for
// a model case, case.json): the domain from DIR/complex.json (simplicial, cell, combinatorial or
// hypergraph; cells in the other library's index order, which is kept), and every operator of
// DIR/operators.json computed from its meaning (`op` + `args`) alone, never from its name and
// never from DIR/operators/. What it is for: checking topos's operators against another
// library's on the same complex (the parity tests, `tdl operators`), and building a golden model
// case's operators (topos/models/zoo/golden_case.hpp). The ops:
//   complex operators   incidence_matrix, hodge_/up_/down_laplacian_matrix, adjacency_matrix,
//                       coadjacency_matrix, normalized_laplacian_matrix (+ coincidence_matrix)
//   normalisations      compute_laplacian_normalized_matrix, compute_x_laplacian_normalized_matrix,
//                       compute_kipf_adjacency_normalized_matrix,
//                         compute_xu_asymmetric_normalized_matrix,
//                       compute_bunch_normalized_matrices
//   algebra             transpose, abs, sum, scale, identity, pinv (an argument that is a string
//                       names an earlier operator of the same case)
// An unknown op, a missing argument, an operator a domain lacks, an operator with a non-finite
// entry, pinv of more than kMaxPinvEntries: a DataError naming the file and the operator.
// Core + nlohmann-json (no LibTorch). This header declares; tdl_case-inl.hpp implements (it
// instantiates every operator of every domain), compiled once into topos::data
// (src/tdl_case.cpp), or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/config.hpp"
#include "topos/core/cell_complex.hpp"
#include "topos/core/combinatorial_complex.hpp"
#include "topos/core/hypergraph.hpp"
#include "topos/core/simplicial_complex.hpp"
#include "topos/core/sparse_matrix.hpp"
#include "topos/data/json.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <type_traits>
#include <variant>
#include <vector>

namespace topos::data {

using SparseOp = Eigen::SparseMatrix<double, Eigen::RowMajor, std::int64_t>;
static_assert(std::is_same_v<SparseOp, SparseMatrix>, "tdl operators are the core operator type");

/// Operators of a case: names in operators.json order, and the matrices by name.
struct Operators {
  std::vector<std::string> order;
  std::map<std::string, SparseOp> by_name;
};

using Domain = std::variant<SimplicialComplex, CellComplex, CombinatorialComplex<>, Hypergraph>;

/// "simplicial", "cell", "combinatorial" or "hypergraph".
inline const char* domain_name(const Domain& d) {
  static const char* names[] = {"simplicial", "cell", "combinatorial", "hypergraph"};
  return names[d.index()];
}

/// The domain of a parsed complex.json `j` (`domain` names the kind; `fallback_domain` is used
/// when it lacks one, e.g. from case.json); errors are DataErrors naming `src`. Cells keep the
/// file's order; nodes are numbered by their position in the node list (rank-0 cells).
Domain parse_domain(const nlohmann::ordered_json& j, const std::string& src,
                    const std::string& fallback_domain = {});

/// The domain of the complex.json file at `complex_json` (see parse_domain).
Domain read_domain(const std::filesystem::path& complex_json,
                   const std::string& fallback_domain = {});

/// The domain case.json names (its "domain" string), or "" when it names none.
inline std::string case_domain(const nlohmann::json& case_json) {
  if (case_json.is_object() && case_json.contains("domain") && case_json["domain"].is_string())
    return case_json["domain"].get<std::string>();
  return {};
}

/// The largest operator (rows x cols) pinv accepts: it is computed dense (32 MB, a 2048 x 2048
/// SVD).
inline constexpr std::int64_t kMaxPinvEntries = std::int64_t{1} << 22;

/// The ops this evaluator knows (for messages and documentation).
std::vector<std::string> known_ops();

/// One operator from its op and args, on `domain`, with `earlier` holding the operators it may
/// name.
SparseOp evaluate_operator(const std::string& name, const std::string& op,
                           const nlohmann::ordered_json& args, const Domain& domain,
                           const Operators& earlier);

/// Every operator of an operators.json ({name: {"op", "args", ...}} in creation order).
Operators compute_operators(const nlohmann::ordered_json& ops, const Domain& domain,
                            const std::string& source = "operators.json");

/// Builds the domain from DIR/complex.json and every operator of DIR/operators.json from its
/// op/args alone (never reads DIR/operators/). Unknown op names: a DataError naming the
/// operator and the op.
Operators compute_operators(const std::filesystem::path& case_dir);

}  // namespace topos::data

namespace topos {
// Deprecated: the reader's old namespace. Write data::compute_operators (etc.).
namespace tdl = data;
}  // namespace topos

#ifdef TOPOS_HEADER_ONLY
#include "topos/data/tdl_case-inl.hpp"
#endif
