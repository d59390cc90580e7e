// tests/fuzz/replay_main.cpp
// Replays saved fuzz inputs (regressions/<harness>/, seeds/<harness>/) through the harnesses
// without libFuzzer: `topos_fuzz_replay <harness> <file or folder>...`. Exit 0 when every input
// was handled; a finding aborts, as it does under the fuzzer.
#include "fuzz_target.hpp"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <vector>

int main(int argc, char** argv) {
  const auto& reg = topos_fuzz::registry();
  if (argc < 2 || !reg.count(argv[1])) {
    std::cerr << "usage: topos_fuzz_replay <harness> <file or folder>...; harnesses:";
    for (const auto& [name, e] : reg) std::cerr << " " << name;
    std::cerr << "\n";
    return 2;
  }
  const auto entry = reg.at(argv[1]);
  std::vector<std::filesystem::path> files;
  for (int i = 2; i < argc; ++i) {
    const std::filesystem::path p(argv[i]);
    if (std::filesystem::is_directory(p)) {
      for (const auto& e : std::filesystem::directory_iterator(p))
        if (e.is_regular_file() && e.path().filename().string()[0] != '.')
          files.push_back(e.path());
    } else if (std::filesystem::exists(p)) {
      files.push_back(p);
    }
  }
  std::sort(files.begin(), files.end());
  for (const auto& f : files) {
    std::ifstream in(f, std::ios::binary);
    const std::vector<char> bytes((std::istreambuf_iterator<char>(in)),
                                  std::istreambuf_iterator<char>());
    std::cerr << argv[1] << ": " << f.filename().string() << " (" << bytes.size() << " bytes)\n";
    entry(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
  }
  std::cout << argv[1] << ": replayed " << files.size() << " inputs\n";
  return 0;
}
