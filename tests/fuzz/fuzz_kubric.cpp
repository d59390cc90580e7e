// Fuzz harness: Kubric metadata.json (data/kubric.hpp).
#include "fuzz_target.hpp"

#include "topos/data/kubric.hpp"

TOPOS_FUZZ_TARGET(kubric) {
  using namespace topos_fuzz;
  try {
    const auto s = topos::data::parse_kubric_metadata(text(data, size), source());
    check(s.num_frames > 0 && !s.instances.empty(), "a scene has frames and instances");
    for (const auto& k : s.instances) {
      check(k.positions.rows() == s.num_frames && k.quaternions.rows() == s.num_frames,
            "one pose per frame");
      check(k.positions.allFinite() && k.quaternions.allFinite(), "finite poses");
      check(k.size > 0, "positive size");
    }
  } catch (const topos::data::DataError& e) {
    expect_error(e.what());
  }
  return 0;
}
