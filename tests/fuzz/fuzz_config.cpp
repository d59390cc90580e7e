// Fuzz harness: the HOPNet configuration JSON a topos checkpoint carries ("topos.config",
// models/hopnet/model.hpp HopnetOptions::from_json): every accepted configuration must be
// within the limits that make its network allocatable.
#include "fuzz_target.hpp"

#include "topos/models/hopnet/model.hpp"

TOPOS_FUZZ_TARGET(config) {
  using namespace topos_fuzz;
  nlohmann::json j;
  try {
    j = topos::data::parse_json(text(data, size), source());
  } catch (const topos::data::DataError& e) {
    expect_error(e.what());
    return 0;
  }
  try {
    const auto o = topos::models::hopnet::HopnetOptions::from_json(j);
    check(o.hidden() > 0 && o.hidden() <= 65536 && o.mlp_layers() >= 1 && o.mlp_layers() <= 64 &&
              o.num_layers() >= 1 && o.num_layers() <= 64,
          "an accepted configuration is allocatable");
    check(topos::models::hopnet::HopnetOptions::from_json(o.to_json()).to_json() == o.to_json(),
          "to_json round-trips");
    if (o.hidden() <= 8 && o.num_layers() <= 2 && o.mlp_layers() <= 3) {
      topos::models::hopnet::Hopnet net(o);
      check(net->num_parameters() > 0, "a network has parameters");
    }
  } catch (const std::invalid_argument&) {
    // from_json's messages say "HOPNet configuration"; the caller (checkpoint_options) adds the
    // file.
  }
  return 0;
}
