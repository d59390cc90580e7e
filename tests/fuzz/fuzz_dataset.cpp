// Fuzz harness: the topos dataset index (dataset.json, data/dataset.hpp) against fixed arrays
// of 2 objects × 4 frames, the shape the seed indexes describe; the arrays' own reader has the
// npy harness.
#include "fuzz_target.hpp"

#include "topos/data/dataset.hpp"

namespace {
topos::data::NpyArray array(std::int64_t cols) {
  topos::data::NpyArray a;
  a.dtype = "f8";
  a.shape = {2, 4, cols};
  std::vector<double> v(static_cast<std::size_t>(2 * 4 * cols));
  for (std::size_t i = 0; i < v.size(); ++i) v[i] = 0.25 * static_cast<double>(i);
  a.bytes.resize(v.size() * sizeof(double));
  std::memcpy(a.bytes.data(), v.data(), a.bytes.size());
  return a;
}
}  // namespace

TOPOS_FUZZ_TARGET(dataset) {
  using namespace topos_fuzz;
  namespace d = topos::data;
  static const d::NpyArray pos = array(3), quat = array(4);
  try {
    const auto index = d::parse_json(text(data, size), source());
    const auto ds = d::Dataset::from_topos(source(), index, pos, quat);
    check(!ds.ids().empty(), "a dataset holds scenes");
    for (auto id : ds.ids()) {
      const auto s = ds.scene(id);
      check(!s.instances.empty(), "a scene holds objects");
      for (const auto& k : s.instances)
        check(k.positions.rows() == 4 && k.quaternions.rows() == 4, "one pose per frame");
    }
  } catch (const d::DataError& e) {
    expect_error(e.what());
  }
  return 0;
}
