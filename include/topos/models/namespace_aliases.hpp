// topos/models/namespace_aliases.hpp
// Deprecated: the simulation models' old namespaces. HOPNet, GNS, MeshGraphNet, FIGNet and the
// baselines live in topos::models::hopnet, ::gns, ::mgn, ::fignet and ::baselines, as their
// folders under topos/models/ say; topos::hopnet (etc.) stay as aliases of them so code written
// against the old names keeps compiling. Write models::hopnet::NAME instead. Every header of
// those families includes this one.
#pragma once

namespace topos::models::hopnet {}
namespace topos::models::gns {}
namespace topos::models::mgn {}
namespace topos::models::fignet {}
namespace topos::models::baselines {}

namespace topos {

// Deprecated aliases: write models::hopnet (etc.).
namespace hopnet = models::hopnet;
namespace gns = models::gns;
namespace mgn = models::mgn;
namespace fignet = models::fignet;
namespace baselines = models::baselines;

}  // namespace topos
