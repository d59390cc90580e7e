// apps/hopnet/viewer.hpp
// The hopnet program's 3D rollout viewer: one self-contained HTML file that opens offline. It
// shows the predicted rollout and the ground truth side by side or overlaid (three.js: lit,
// shadowed, orbit controls, one colour per object), plays, pauses and scrubs through the frames,
// and plots the per-frame position error under the scene with the current frame marked
// (Chart.js). The page is web/viewer.html; this header fills it with the scenes' meshes and
// poses as JSON. URL parameters: ?frame=N (open paused at frame N), ?scene=I, ?mode=overlay.
#pragma once

#include "web_assets.hpp"

#include "topos/io/atomic_file.hpp"
#include "topos/models/hopnet/features.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <string>
#include <utility>
#include <vector>

namespace hopnet_viewer {

/// A per-frame error curve drawn under the scene.
struct ErrorCurve {
  std::string label;
  std::vector<double> values;  ///< per frame; NaN where undefined
};

struct ViewerScene {
  std::string name;
  const topos::sim::Scene* scene = nullptr;
  std::vector<topos::sim::Poses> predicted;  ///< rollout poses, frame 0 onwards
  std::vector<ErrorCurve> errors;            ///< the first is the prediction's position RMSE
};

inline nlohmann::json viewer_scene_json(const ViewerScene& v) {
  const auto& s = *v.scene;
  if (v.errors.empty()) throw std::invalid_argument("viewer scene " + v.name + ": no error curve");
  nlohmann::json errors = nlohmann::json::array();
  for (const auto& c : v.errors) {
    nlohmann::json values = nlohmann::json::array();
    for (double x : c.values)
      values.push_back(std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(nullptr));
    errors.push_back({{"label", c.label}, {"values", values}});
  }
  nlohmann::json j{{"name", v.name}, {"objects", nlohmann::json::array()}, {"errors", errors}};
  std::vector<std::size_t> shown;
  for (std::size_t o = 0; o < s.num_objects(); ++o) {
    if (s.objects[o].is_floor) continue;
    shown.push_back(o);
    const auto& m = s.objects[o].mesh;
    std::vector<double> verts;
    std::vector<std::int64_t> faces;
    for (Eigen::Index r = 0; r < m.vertices.rows(); ++r)
      for (int c = 0; c < 3; ++c) verts.push_back(std::round(m.vertices(r, c) * 1e5) / 1e5);
    for (Eigen::Index r = 0; r < m.faces.rows(); ++r)
      for (int c = 0; c < 3; ++c) faces.push_back(m.faces(r, c));
    j["objects"].push_back({{"shape", s.objects[o].shape}, {"v", verts}, {"f", faces}});
  }
  const std::size_t frames = v.predicted.size();
  auto poses = [&](auto get) {
    nlohmann::json all = nlohmann::json::array();
    for (std::size_t t = 0; t < frames; ++t) {
      std::vector<double> row;
      for (auto o : shown) {
        const auto [p, q] = get(t, o);
        for (int c = 0; c < 3; ++c) row.push_back(std::round(p(c) * 1e5) / 1e5);
        for (int c = 0; c < 4; ++c) row.push_back(std::round(q(c) * 1e5) / 1e5);
      }
      all.push_back(row);
    }
    return all;
  };
  j["gt"] = poses([&](std::size_t t, std::size_t o) {
    const auto f = static_cast<std::int64_t>(
        std::min<std::size_t>(t, static_cast<std::size_t>(s.num_frames - 1)));
    return std::pair<Eigen::Vector3d, Eigen::Vector4d>{s.position(f, o), s.quaternion(f, o)};
  });
  j["pred"] = poses([&](std::size_t t, std::size_t o) {
    const auto i = static_cast<Eigen::Index>(o);
    return std::pair<Eigen::Vector3d, Eigen::Vector4d>{
        v.predicted[t].positions.row(i).transpose(), v.predicted[t].quaternions.row(i).transpose()};
  });
  return j;
}

/// The viewer page for `scenes`, with three.js and Chart.js inlined (web_assets.hpp).
inline std::string viewer_html(const std::string& title, const std::vector<ViewerScene>& scenes) {
  if (scenes.empty()) throw std::invalid_argument("the viewer needs at least one scene");
  // fps: playback speed at 1x; the first 4 frames are given to the model, not predicted.
  nlohmann::json data{
      {"title", title}, {"fps", 60}, {"given_frames", 4}, {"scenes", nlohmann::json::array()}};
  for (const auto& s : scenes) data["scenes"].push_back(viewer_scene_json(s));
  return hopnet_web::fill_template(hopnet_web::templates::viewer_html,
                                   {{"CHARTJS", hopnet_web::chart_js_script()},
                                    {"IMPORTMAP", hopnet_web::three_import_map()},
                                    {"DATA", hopnet_web::script_json(data)}},
                                   "viewer");
}

/// Writes the viewer for `scenes` to `path` (atomically).
inline void write_viewer_html(const std::string& path, const std::string& title,
                              const std::vector<ViewerScene>& scenes) {
  topos::io::write_file_atomic(path, viewer_html(title, scenes));
}

}  // namespace hopnet_viewer
