// Fuzz harness: a tdl case (topos/data/tdl_case.hpp), the files `tdl operators --case DIR` reads.
// The input is complex.json, then optionally a NUL byte and operators.json, then optionally a
// NUL byte and case.json (its "domain" is the fallback when complex.json names none).
#include "fuzz_target.hpp"

#include "topos/data/tdl_case.hpp"

#include <cmath>
#include <cstdint>
#include <string>

namespace {

// The files' names in errors; each contains source(), so an error naming its file names the
// input.
std::string file(const char* name) {
  return std::string(topos_fuzz::source()) + "/" + name;
}

}  // namespace

TOPOS_FUZZ_TARGET(tdl) {
  using namespace topos_fuzz;
  namespace t = topos::tdl;
  namespace d = topos::data;
  const std::string all = text(data, size);
  const std::size_t a = all.find('\0');
  const std::size_t b = a == std::string::npos ? a : all.find('\0', a + 1);
  const std::string complex_text = all.substr(0, a);
  const bool has_ops = a != std::string::npos;
  const std::string ops_text =
      has_ops ? all.substr(a + 1, b == std::string::npos ? b : b - a - 1) : std::string();
  const bool has_case = b != std::string::npos;
  const std::string case_text = has_case ? all.substr(b + 1) : std::string();
  try {
    std::string fallback;
    if (has_case) fallback = t::case_domain(d::parse_json(case_text, file("case.json")));
    const auto cj = d::parse_ordered_json(complex_text, file("complex.json"));
    const t::Domain domain = t::parse_domain(cj, file("complex.json"), fallback);
    // Nodes are the listed ones, numbered by position.
    const std::vector<std::int64_t> shape =
        std::visit([](const auto& dom) { return dom.shape(); }, domain);
    check(!shape.empty(), "a domain has nodes (rank 0)");
    const bool ranked = domain.index() == 0 || domain.index() == 2;  // simplicial, combinatorial
    const auto& listed = ranked ? cj["cells"]["0"] : cj["nodes"];
    check(shape[0] == static_cast<std::int64_t>(listed.size()), "one node per listed node");
    if (!has_ops) return 0;

    const auto spec = d::parse_ordered_json(ops_text, file("operators.json"));
    const t::Operators ops = t::compute_operators(spec, domain, file("operators.json"));
    check(ops.order.size() == ops.by_name.size() && ops.order.size() == spec.size(),
          "every listed operator is computed once");
    // A rank-0 incidence is TopoNetX's 1 x n_0 row of ones (simplicial) or 0 x n_0 (cell).
    const auto is_count = [&](Eigen::Index n) {
      if (n == 0 || n == 1) return true;
      for (auto s : shape)
        if (s == n) return true;
      return false;
    };
    for (const auto& name : ops.order) {
      check(ops.by_name.count(name) == 1, "each name in order has its matrix");
      const t::SparseOp& m = ops.by_name.at(name);
      check(is_count(m.rows()) && is_count(m.cols()),
            "an operator's rows and columns are the cells of some rank (or 0, 1)");
      check(m.isCompressed(), "operators are compressed");
      for (Eigen::Index i = 0; i < m.outerSize(); ++i)
        for (t::SparseOp::InnerIterator it(m, i); it; ++it) {
          check(it.row() >= 0 && it.row() < m.rows() && it.col() >= 0 && it.col() < m.cols(),
                "entries inside the matrix");
          check(std::isfinite(it.value()), "finite entries");
        }
    }
  } catch (const d::DataError& e) {
    expect_error(e.what());
  }
  return 0;
}
