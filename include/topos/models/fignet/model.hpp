// topos/models/fignet/model.hpp
// FIGNet (Allen et al. 2022, face-interaction graph networks) as a graph-network schedule, with
// the layout of the unofficial reimplementation that ships with the HOPNet reference
// (AmauryWEI/hopnet, fignet/): mesh and object nodes (12 features each), mesh-object and
// object-mesh edges (8), face-face hyperedges of 3 sender/receiver vertex slots (34), optional
// mesh-mesh edges (8; off in its MOVi configurations), latent 128, 10 blocks of 2-hidden-layer
// MLPs with LayerNorm. Parameter names are its state dict's; with the defaults 5,559,430
// parameters in 452 tensors (docs/design/baselines.md, part 2). Features: fignet/features.hpp.
#pragma once

#include "topos/models/gns/model.hpp"
#include "topos/models/gns/options.hpp"
#include "topos/models/namespace_aliases.hpp"

namespace topos::models::fignet {

struct FignetOptions {
  gns::NetworkOptions network;
  bool mesh_edges = false;        ///< the reimplementation's mm edges (leave_out_mm false)
  double collision_radius = 0.1;  ///< face pairs within this distance become hyperedges

  nlohmann::json to_json() const {
    nlohmann::json j{{"model", "fignet"}};
    network.to_json(j);
    j["mesh_edges"] = mesh_edges;
    j["collision_radius"] = collision_radius;
    return j;
  }
  static FignetOptions from_json(const nlohmann::json& j) {
    FignetOptions o;
    o.network.from_json(j, "fignet", {"mesh_edges", "collision_radius"});
    if (j.contains("mesh_edges")) {
      if (!j["mesh_edges"].is_boolean())
        throw std::invalid_argument("fignet configuration: mesh_edges must be true or false");
      o.mesh_edges = j["mesh_edges"].get<bool>();
    }
    o.collision_radius = gns::positive_radius(j, "fignet", "collision_radius", 0.1);
    return o;
  }
};

inline gns::GraphNetworkSpec fignet_spec(const FignetOptions& o) {
  gns::GraphNetworkSpec s = o.network.spec();
  // Both node sets share one normaliser, as do the regular edge sets (the reimplementation's
  // _node_normalizer and _regular_edge_normalizer).
  s.nodes = {{"mesh", 12, "_m_encoder", "mesh_node_fn", "_m_decoder", 3, "node"},
             {"object", 12, "_o_encoder", "obj_node_fn", "_o_decoder", 3, "node"}};
  s.edges = {{"mo", "mesh", "object", 8, 1, "_emo_encoder", "mo_edge_fn", "edge"},
             {"om", "object", "mesh", 8, 1, "_eom_encoder", "om_edge_fn", "edge"}};
  if (o.mesh_edges)
    s.edges.push_back({"mm", "mesh", "mesh", 8, 1, "_emm_encoder", "mm_edge_fn", "edge"});
  s.edges.push_back({"ff", "mesh", "mesh", 34, 3, "_eff_encoder", "ff_edge_fn", "face_edge"});
  return s;
}

/// The FIGNet module: parameters at _encode_process_decode.<the reimplementation's names>.
inline gns::GraphNetwork make_fignet(const FignetOptions& o) {
  return gns::GraphNetwork(fignet_spec(o), "_encode_process_decode");
}

}  // namespace topos::models::fignet
