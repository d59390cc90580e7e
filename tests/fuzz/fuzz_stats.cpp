// Fuzz harness: HOPNet normalisation statistics JSON (models/hopnet/normalization.hpp).
#include "fuzz_target.hpp"

#include "topos/models/hopnet/normalization.hpp"

TOPOS_FUZZ_TARGET(stats) {
  using namespace topos_fuzz;
  try {
    const auto s = topos::models::hopnet::parse_stats_json(text(data, size), source());
    // The file's own layout: x0's width varies and x4/t4 are absent without object cells.
    const auto keys = s.keys();
    check(s.mean.size() == keys.size() && s.std.size() == keys.size(), "only the layout's blocks");
    for (const auto& [k, n] : keys) {
      check(s.mean.count(k) && s.std.count(k), "every block of the layout is present");
      check(s.mean.at(k).size() == n && s.std.at(k).size() == n, "every block has its columns");
      for (double v : s.std.at(k)) check(v > 0, "positive std");
    }
  } catch (const topos::data::DataError& e) {
    expect_error(e.what());
  }
  return 0;
}
