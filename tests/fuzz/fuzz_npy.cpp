// Fuzz harness: NumPy .npy arrays (data/npy.hpp). A header may claim any shape: the reader must
// refuse what the bytes cannot hold before allocating (libFuzzer's -malloc_limit_mb catches it).
#include "fuzz_target.hpp"

#include "topos/data/npy.hpp"

#include <sstream>

TOPOS_FUZZ_TARGET(npy) {
  using namespace topos_fuzz;
  std::istringstream in(text(data, size));
  try {
    const auto a = topos::data::read_npy(in, source());
    const auto item = topos::data::npy_item_size(a.dtype);
    check(item > 0, "a supported dtype");
    check(a.bytes.size() == static_cast<std::size_t>(a.size()) * item,
          "the data holds every element");
    check(a.bytes.size() <= size, "no more data than input");
    const auto v = a.as<double>();
    check(v.size() == static_cast<std::size_t>(a.size()), "conversion keeps every element");
  } catch (const std::runtime_error& e) {
    expect_error(e.what());
  }
  return 0;
}
