// topos/models/hopnet/lifting_options.hpp
// How a scene is lifted for HOPNet: the feature mode (reference or native, see features.hpp), the
// member of the family (Architecture), SceneLiftingOptions and the input feature widths. Std only.
#pragma once

#include "topos/models/namespace_aliases.hpp"

#include <array>
#include <cstdint>
#include <stdexcept>
#include <string>

namespace topos::models::hopnet {

enum class FeatureMode { reference, native };

inline FeatureMode feature_mode_from_string(const std::string& s) {
  if (s == "reference") return FeatureMode::reference;
  if (s == "native") return FeatureMode::native;
  throw std::invalid_argument("unknown mode '" + s + "' (reference or native)");
}
inline const char* to_string(FeatureMode m) {
  return m == FeatureMode::reference ? "reference" : "native";
}

/// Feature widths (data/create_ccs.py): x0 16, x1 8, x2 3, x3 28, x4 13; targets 3.
inline constexpr std::array<int, 5> kFeatureWidth{16, 8, 3, 28, 13};

/// The member of the HOPNet family a complex is lifted for (the reference's models/ablations.py):
/// hopnet (object cells, sequential layer), no_object_cells (a virtual node per object joined to
/// its nodes by spoke edges, no rank-4 features) or no_sequential (every rank pair at once, with
/// the extra adjacencies and incidences that needs).
enum class Architecture { hopnet, no_object_cells, no_sequential };

inline Architecture architecture_from_string(const std::string& s) {
  if (s == "hopnet") return Architecture::hopnet;
  if (s == "no_object_cells") return Architecture::no_object_cells;
  if (s == "no_sequential") return Architecture::no_sequential;
  throw std::invalid_argument("unknown architecture '" + s +
                              "' (hopnet, no_object_cells, no_sequential)");
}
inline const char* to_string(Architecture a) {
  return a == Architecture::hopnet
             ? "hopnet"
             : (a == Architecture::no_object_cells ? "no_object_cells" : "no_sequential");
}

/// How a HOPNet scene is lifted to a combinatorial complex: feature mode, architecture, and
/// whether x0 keeps the centre-mass distances r0, rt (columns 8..15; the "no centre-mass
/// distance" ablation drops them).
struct SceneLiftingOptions {
  FeatureMode mode = FeatureMode::reference;
  Architecture architecture = Architecture::hopnet;
  bool center_mass_distance = true;
  /// x0's columns: 16 (8 without the centre-mass distances), plus the 5 object columns of x4
  /// (type, mass, friction, restitution) when objects are virtual nodes.
  std::int64_t x0_width() const {
    return (center_mass_distance ? 16 : 8) +
           (architecture == Architecture::no_object_cells ? 5 : 0);
  }
  bool object_cells() const { return architecture != Architecture::no_object_cells; }
};

/// Deprecated: the earlier name, which TopoBench's graph liftings used too.
using LiftingOptions = SceneLiftingOptions;

}  // namespace topos::models::hopnet
