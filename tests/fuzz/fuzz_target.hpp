// tests/fuzz/fuzz_target.hpp
// One source per fuzz harness, two builds: with TOPOS_LIBFUZZER (CMake option TOPOS_FUZZ) the
// harness is libFuzzer's LLVMFuzzerTestOneInput; otherwise it registers itself by name so that
// the regression replay (replay_main.cpp, replay_torch.cpp) runs every saved input through the
// same code on every test run, without libFuzzer.
//
// A harness feeds the bytes to a reader and lets only the reader's documented errors through
// (expect_error); anything else (a crash, a sanitizer report, another exception, an error that
// does not name the input) is a finding.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>

namespace topos_fuzz {

using Entry = int (*)(const std::uint8_t*, std::size_t);

inline std::map<std::string, Entry>& registry() {
  static std::map<std::string, Entry> r;
  return r;
}

struct Register {
  Register(const char* name, Entry e) { registry()[name] = e; }
};

/// The name every harness gives its input; errors must mention it.
inline const char* source() {
  return "fuzz-input";
}

/// Aborts (a finding) when a reader's error does not name its input.
inline void expect_error(const std::string& what) {
  if (what.find(source()) == std::string::npos) {
    std::fprintf(stderr, "error message does not name the input: %s\n", what.c_str());
    std::abort();
  }
}

/// Aborts (a finding) when an invariant of a successful read fails.
inline void check(bool ok, const char* what) {
  if (!ok) {
    std::fprintf(stderr, "invariant violated: %s\n", what);
    std::abort();
  }
}

inline std::string text(const std::uint8_t* data, std::size_t size) {
  return std::string(reinterpret_cast<const char*>(data), size);
}

}  // namespace topos_fuzz

#ifdef TOPOS_LIBFUZZER
#define TOPOS_FUZZ_TARGET(name) \
  extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
#else
#define TOPOS_FUZZ_TARGET(name)                                                           \
  static int topos_fuzz_##name(const std::uint8_t* data, std::size_t size);               \
  static const topos_fuzz::Register topos_fuzz_register_##name(#name, topos_fuzz_##name); \
  static int topos_fuzz_##name(const std::uint8_t* data, std::size_t size)
#endif
