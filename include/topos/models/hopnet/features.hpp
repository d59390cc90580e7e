// topos/models/hopnet/features.hpp
// HOPNet's complex and input features at one timestep (data/create_ccs.py), no LibTorch.
//
// HopnetGeometry holds what is static in a scene: the global node numbering (objects in order,
// floor last), the unique edges in first-seen order with their feature direction, each global
// face's nodes and edges. build_frame() adds what changes per frame: the faces in contact and
// the contact cells (ranks 2 and 3), their incidences, and the raw features x0..x4 in double.
//
// Two modes (FeatureMode):
//  - reference: the published model's inputs, quirks included: contacts from the reference
//    vertex-proximity detector, PhysX's triangle distance (sometimes squared), the CPython
//    frozenset edge direction, last-write-wins face normals, and the role-mixing buffer of
//    B23 (a face that is face0 in one contact and face1 in another sends into both halves).
//  - native: exact face pairs within d_c with their Euclidean distance, edge direction from the
//    mesh's orientation, each face's normal from its closest partner, and B23's two halves by
//    the pair's own role.
//
// The pieces: lifting_options.hpp (FeatureMode, Architecture, SceneLiftingOptions), geometry.hpp
// (HopnetGeometry, pose_objects; the scene and its poses are sim/scene.hpp's), contact_cells.hpp
// (contact candidates and their geometry), frame.hpp (build_frame, HopnetFrame) and
// neighborhoods.hpp (hopnet_neighborhoods).
#pragma once

#include "topos/models/hopnet/contact_cells.hpp"
#include "topos/models/hopnet/frame.hpp"
#include "topos/models/hopnet/geometry.hpp"
#include "topos/models/hopnet/lifting_options.hpp"
#include "topos/models/hopnet/neighborhoods.hpp"
#include "topos/models/hopnet/scene.hpp"
#include "topos/models/namespace_aliases.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <fstream>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>
