// topos/data/kubric.hpp
// Reading Kubric's metadata.json (the fields the HOPNet reference reads): metadata.num_instances,
// num_frames, seed, and per instance asset_id, shape, size, mass, friction, restitution,
// positions (frames × 3) and quaternions (frames × 4, w x y z). Files that list only the visible
// objects are read as they are. Errors name the file and the field. nlohmann-json + Eigen.
#pragma once

#include "topos/data/json.hpp"

#include <nlohmann/json.hpp>

#include <Eigen/Core>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::data {

struct KubricInstance {
  std::string asset_id, shape;
  double size = 1, mass = 0, friction = 0, restitution = 0;
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> positions;
  Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor> quaternions;  ///< w, x, y, z
};

struct KubricScene {
  std::int64_t num_frames = 0, seed = -1;
  std::vector<KubricInstance> instances;
  std::string source;
};

namespace detail {
template <int C>
Eigen::Matrix<double, Eigen::Dynamic, C, Eigen::RowMajor> read_rows(const nlohmann::json& j,
                                                                    const std::string& where,
                                                                    std::int64_t frames) {
  if (!j.is_array()) throw DataError(where + ": expected an array");
  if (static_cast<std::int64_t>(j.size()) != frames)
    throw DataError(where + ": has " + std::to_string(j.size()) + " rows, metadata.num_frames is " +
                    std::to_string(frames));
  Eigen::Matrix<double, Eigen::Dynamic, C, Eigen::RowMajor> m(frames, C);
  for (std::int64_t r = 0; r < frames; ++r) {
    const auto& row = j[static_cast<std::size_t>(r)];
    if (!row.is_array() || row.size() != C)
      throw DataError(where + "[" + std::to_string(r) + "]: expected " + std::to_string(C) +
                      " numbers");
    for (int c = 0; c < C; ++c) {
      if (!row[static_cast<std::size_t>(c)].is_number())
        throw DataError(where + "[" + std::to_string(r) + "]: not a number");
      m(r, c) = row[static_cast<std::size_t>(c)].get<double>();
      if (!std::isfinite(m(r, c)))
        throw DataError(where + "[" + std::to_string(r) + "]: non-finite value");
    }
  }
  return m;
}
}  // namespace detail

/// Parses Kubric metadata JSON text; `source` names it in errors.
inline KubricScene parse_kubric_metadata(const std::string& text, const std::string& source) {
  const nlohmann::json j = parse_json(text, source);
  const auto field = [&](const nlohmann::json& obj, const char* key,
                         const std::string& where) -> const nlohmann::json& {
    if (!obj.is_object() || !obj.contains(key))
      throw DataError(source + ": missing field '" + where + key + "'");
    return obj[key];
  };
  KubricScene s;
  s.source = source;
  const auto& meta = field(j, "metadata", "");
  try {
    s.num_frames =
        get_integer(field(meta, "num_frames", "metadata."), source + ": metadata.num_frames");
    const auto n =
        get_integer(field(meta, "num_instances", "metadata."), source + ": metadata.num_instances");
    if (meta.contains("seed")) s.seed = get_integer(meta["seed"], source + ": metadata.seed");
    const auto& inst = field(j, "instances", "");
    if (!inst.is_array()) throw DataError(source + ": 'instances' is not an array");
    if (s.num_frames <= 0) throw DataError(source + ": metadata.num_frames must be positive");
    if (n < static_cast<std::int64_t>(inst.size()))
      throw DataError(source + ": metadata.num_instances (" + std::to_string(n) +
                      ") is below the " + std::to_string(inst.size()) + " instances listed");
    for (std::size_t i = 0; i < inst.size(); ++i) {
      const std::string w = "instances[" + std::to_string(i) + "].";
      KubricInstance k;
      k.asset_id = field(inst[i], "asset_id", w).get<std::string>();
      k.shape = inst[i].contains("shape") ? inst[i]["shape"].get<std::string>() : k.asset_id;
      k.size = field(inst[i], "size", w).get<double>();
      k.mass = field(inst[i], "mass", w).get<double>();
      k.friction = field(inst[i], "friction", w).get<double>();
      k.restitution = field(inst[i], "restitution", w).get<double>();
      k.positions = detail::read_rows<3>(field(inst[i], "positions", w),
                                         source + ": " + w + "positions", s.num_frames);
      k.quaternions = detail::read_rows<4>(field(inst[i], "quaternions", w),
                                           source + ": " + w + "quaternions", s.num_frames);
      if (!(k.size > 0)) throw DataError(source + ": " + w + "size must be positive");
      s.instances.push_back(std::move(k));
    }
  } catch (const nlohmann::json::exception& e) {
    throw DataError(source + ": wrong type in metadata: " + e.what());
  }
  if (s.instances.empty()) throw DataError(source + ": the scene has no instances");
  return s;
}

/// Reads `path`, a metadata.json or a folder holding one.
inline KubricScene read_kubric_metadata(std::filesystem::path path) {
  if (std::filesystem::is_directory(path)) path /= "metadata.json";
  return parse_kubric_metadata(read_text_file(path), path.string());
}

}  // namespace topos::data
