// topos/models/mgn/model.hpp
// MeshGraphNet (Pfaff et al. 2021) for rigid bodies, as the FIGNet paper uses it for a baseline:
// an encode-process-decode graph network over mesh nodes (12 features, FIGNet's layout), mesh
// edges (8) and world edges between nodes of different objects within a radius (4), predicting
// per-node accelerations that the rollout turns into rigid poses by shape matching. `mgn` uses
// the radius 0.1 (HOPNet's and FIGNet's collision radius), `mgn-large-radius` 0.3; the choices
// the papers leave open are listed in docs/baselines.md. Features: mgn/features.hpp.
#pragma once

#include "topos/models/gns/model.hpp"
#include "topos/models/gns/options.hpp"
#include "topos/models/namespace_aliases.hpp"

namespace topos::models::mgn {

struct MgnOptions {
  gns::NetworkOptions network;
  double world_edge_radius = 0.1;

  nlohmann::json to_json() const {
    nlohmann::json j{{"model", "mgn"}};
    network.to_json(j);
    j["world_edge_radius"] = world_edge_radius;
    return j;
  }
  static MgnOptions from_json(const nlohmann::json& j) {
    MgnOptions o;
    o.network.from_json(j, "mgn", {"world_edge_radius"});
    o.world_edge_radius = gns::positive_radius(j, "mgn", "world_edge_radius", 0.1);
    return o;
  }
};

inline gns::GraphNetworkSpec mgn_spec(const MgnOptions& o) {
  gns::GraphNetworkSpec s = o.network.spec();
  s.nodes = {{"mesh", 12, "_node_encoder", "node_fn", "_node_decoder", 3, "node"}};
  s.edges = {
      {"mesh_edges", "mesh", "mesh", 8, 1, "_mesh_edge_encoder", "mesh_edge_fn", "mesh_edge"},
      {"world_edges", "mesh", "mesh", 4, 1, "_world_edge_encoder", "world_edge_fn", "world_edge"}};
  return s;
}

inline gns::GraphNetwork make_mgn(const MgnOptions& o) {
  return gns::GraphNetwork(mgn_spec(o), "_encode_process_decode");
}

}  // namespace topos::models::mgn
