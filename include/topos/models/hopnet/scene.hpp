// topos/models/hopnet/scene.hpp
// Deprecated: the scene moved to topos/sim/scene.hpp (namespace topos::sim), shared by every
// simulator. These names stay here as aliases so code that includes this header keeps compiling;
// include topos/sim/scene.hpp and write sim::Scene (etc.) instead.
#pragma once

#include "topos/models/namespace_aliases.hpp"
#include "topos/sim/scene.hpp"

namespace topos::models::hopnet {

using sim::floor_mesh;
using sim::floor_object;
using sim::make_scene;
using sim::MeshLibrary;
using sim::pose_scene;
using sim::Poses;
using sim::RowMatrix;
using sim::Scene;
using sim::scene_poses;
using sim::SceneObject;

}  // namespace topos::models::hopnet
