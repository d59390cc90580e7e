// tests/fuzz/replay_torch.cpp
// The LibTorch harnesses' saved inputs (regressions/, seeds/), replayed inside topos_nn_tests
// (one torch executable, one precompiled header) without libFuzzer.
#include "fuzz/fuzz_checkpoint.cpp"
#include "fuzz/fuzz_config.cpp"

#include <catch2/catch.hpp>

#include <filesystem>
#include <fstream>
#include <iterator>

namespace {
void replay(const std::string& harness) {
  const auto entry = topos_fuzz::registry().at(harness);
  std::size_t n = 0;
  for (const char* kind : {"regressions", "seeds"}) {
    const auto dir = std::filesystem::path(TOPOS_FUZZ_DIR) / kind / harness;
    if (!std::filesystem::is_directory(dir)) continue;
    for (const auto& e : std::filesystem::directory_iterator(dir)) {
      if (!e.is_regular_file()) continue;
      std::ifstream in(e.path(), std::ios::binary);
      const std::vector<char> bytes((std::istreambuf_iterator<char>(in)),
                                    std::istreambuf_iterator<char>());
      INFO(e.path().string());
      entry(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
      ++n;
    }
  }
  CHECK(n > 0);
}
}  // namespace

TEST_CASE("fuzz regressions replay: checkpoint") {
  replay("checkpoint");
}
TEST_CASE("fuzz regressions replay: config") {
  replay("config");
}
