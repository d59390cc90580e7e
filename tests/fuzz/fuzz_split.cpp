// Fuzz harness: split files (data/dataset.hpp parse_split_json) and the seed ranges of the
// command line (parse_seed_range), which reach the same lists.
#include "fuzz_target.hpp"

#include "topos/data/dataset.hpp"

#include <set>

TOPOS_FUZZ_TARGET(split) {
  using namespace topos_fuzz;
  namespace d = topos::data;
  if (size == 0) return 0;
  const std::string input = text(data + 1, size - 1);
  if (data[0] & 1) {
    try {
      const auto seeds = d::parse_seed_range(input);
      check(!seeds.empty(), "a range names seeds");
      for (std::size_t i = 1; i < seeds.size(); ++i)
        check(seeds[i - 1] < seeds[i], "ascending unique seeds");
      if (seeds.size() <= 100000) {  // the split shuffles: keep executions quick
        const auto s = d::reference_split(seeds);
        check(s.train.size() + s.val.size() + s.test.size() == seeds.size(),
              "the split partitions the seeds");
      }
    } catch (const d::DataError& e) {
      // Seed ranges come from the command line: the message names the range, not a file.
      if (std::string(e.what()).find("seed range") == std::string::npos) std::abort();
    }
    return 0;
  }
  try {
    const auto s = d::parse_split_json(input, source());
    std::set<std::int64_t> all;
    for (const auto* part : {&s.train, &s.val, &s.test})
      for (auto id : *part) check(all.insert(id).second, "no seed in two parts");
    std::vector<std::int64_t> ids(all.begin(), all.end());
    for (const char* part : {"train", "val", "test", "all"})
      check(d::split_part(s, part, ids).size() <= ids.size(), "a part of the seeds");
  } catch (const d::DataError& e) {
    expect_error(e.what());
  }
  return 0;
}
