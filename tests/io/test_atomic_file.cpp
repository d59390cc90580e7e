// Tests of topos/io/atomic_file.hpp (FileGroup, recover_file_group) and topos/util/csv_log.hpp:
// the states a kill can leave, rebuilt by hand, and what recovery and a resumed log make of them.
// The kills themselves: tests/cli/crash_resume.cmake.
#include "topos/io/atomic_file.hpp"
#include "topos/util/csv_log.hpp"

#include <catch2/catch.hpp>

#include "support/fresh_dir.hpp"

#include <filesystem>
#include <fstream>
#include <sstream>
#include <type_traits>

namespace fs = std::filesystem;

// The names before io/ had its namespace still name the same types.
static_assert(std::is_same_v<topos::FileGroup, topos::io::FileGroup>);

namespace {
std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}
void put(const fs::path& p, const std::string& text) {
  std::ofstream(p, std::ios::binary) << text;
}
}  // namespace

TEST_CASE("a file group replaces its files together, and recovery completes an interrupted commit",
          "[io][atomic]") {
  const auto d = topos::testing::fresh_dir("io_group");
  const auto a = (d / "a").string(), b = (d / "b").string(), journal = (d / "journal").string();
  put(a, "old-a");
  put(b, "old-b");
  {
    topos::io::FileGroup g(journal);
    topos::io::write_file_atomic(g.stage(a), std::string("new-a"));
    topos::io::write_file_atomic(g.stage(b), std::string("new-b"));
    CHECK(slurp(a) == "old-a");  // staged only
    g.commit();
  }
  CHECK(slurp(a) == "new-a");
  CHECK(slurp(b) == "new-b");
  CHECK(!fs::exists(journal));
  CHECK(!fs::exists(a + ".next"));

  // Killed before the journal: staged files, no journal. Recovery keeps the old set.
  put(a, "old-a");
  put(b, "old-b");
  put(a + ".next", "new-a");
  put(b + ".next.tmp", "new-");
  topos::io::recover_file_group(journal);
  CHECK(slurp(a) == "old-a");
  CHECK(slurp(b) == "old-b");

  // Killed after the journal and the first rename: recovery renames the rest.
  put(a, "new-a");
  fs::remove(a + ".next");
  put(b + ".next", "new-b");
  put(journal, a + "\n" + b + "\n");
  topos::io::recover_file_group(journal);
  CHECK(slurp(a) == "new-a");
  CHECK(slurp(b) == "new-b");
  CHECK(!fs::exists(journal));
  CHECK(!fs::exists(b + ".next"));
  topos::io::recover_file_group(journal);  // nothing left to do
  CHECK(slurp(b) == "new-b");
  fs::remove_all(d);
}

TEST_CASE("a resumed CSV log keeps the header and the committed rows, never a row cut short",
          "[io][log]") {
  const auto d = topos::testing::fresh_dir("io_log");
  const auto steps = (d / "steps.csv").string();
  put(steps, "epoch,step,loss\n0,1,0.5\n0,2,0.4\n1,3,0.3\n1,4,0.2\n2,5,0.");
  topos::truncate_csv_log(steps, 1, 3);
  CHECK(slurp(steps) == "epoch,step,loss\n0,1,0.5\n0,2,0.4\n1,3,0.3\n");
  put(steps, "epoch,step,loss\n0,1,0.5\n0,2,0.4\n0,3,0.");
  topos::truncate_csv_log(steps, 1, 99);  // only the row cut short goes
  CHECK(slurp(steps) == "epoch,step,loss\n0,1,0.5\n0,2,0.4\n");
  topos::truncate_csv_log(steps, 1, 0);
  CHECK(slurp(steps) == "epoch,step,loss\n");
  topos::truncate_csv_log((d / "missing.csv").string(), 0, 1);
  CHECK(!fs::exists(d / "missing.csv"));
  fs::remove_all(d);
}
