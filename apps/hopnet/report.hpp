// apps/hopnet/report.hpp
// The hopnet program's HTML report: `hopnet evaluate` writes index.html (the error table at the
// paper's horizons, error-vs-frame plots with a mean ± std band for topos and the
// constant-velocity baseline beside the paper's points, a per-scene table with links into the
// viewer, and the training curves when the checkpoint's folder has its logs); `hopnet plot`
// writes the training curves alone. The plots are Chart.js (web_assets.hpp); the page is
// web/report.html, filled with the numbers as JSON. Also what the report reads: the training
// logs (steps.csv, epochs.csv), the paper's result tables (docs/reproduction.md) and the
// dataset kind, inferred from the scenes' shapes and sizes.
#pragma once

#include "web_assets.hpp"

#include "topos/data/dataset.hpp"
#include "topos/io/atomic_file.hpp"
#include "topos/sim/rollout.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace hopnet_report {

// ---- training logs ----------------------------------------------------------------------------

/// A CSV file of numbers with a header row, by column name. Lines that repeat the header (a
/// resumed run appends one) are skipped; a short row or a non-number is a DataError naming the
/// file, the line and the column.
struct CsvTable {
  std::vector<std::string> columns;
  std::vector<std::vector<double>> rows;

  /// The column `name`; a missing one is a DataError naming `source`.
  std::vector<double> column(const std::string& name, const std::string& source) const {
    for (std::size_t c = 0; c < columns.size(); ++c)
      if (columns[c] == name) {
        std::vector<double> v;
        for (const auto& r : rows) v.push_back(r[c]);
        return v;
      }
    throw topos::data::DataError(source + ": no column '" + name + "'");
  }
  bool has(const std::string& name) const {
    return std::find(columns.begin(), columns.end(), name) != columns.end();
  }
};

inline CsvTable read_csv_numbers(const std::filesystem::path& path) {
  std::istringstream in(topos::data::read_text_file(path));
  const std::string source = path.string();
  const auto split = [](const std::string& line) {
    std::vector<std::string> f;
    std::string cell;
    std::istringstream s(line);
    while (std::getline(s, cell, ',')) f.push_back(cell);
    if (!line.empty() && line.back() == ',') f.emplace_back();
    return f;
  };
  CsvTable t;
  std::string line, header;
  for (int n = 1; std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    if (header.empty()) {
      header = line;
      t.columns = split(line);
      continue;
    }
    if (line == header) continue;
    const auto f = split(line);
    if (f.size() != t.columns.size())
      throw topos::data::DataError(source + ":" + std::to_string(n) + ": " +
                                   std::to_string(f.size()) + " fields, the header has " +
                                   std::to_string(t.columns.size()));
    std::vector<double> row;
    for (std::size_t c = 0; c < f.size(); ++c) {
      char* end = nullptr;
      const double v = std::strtod(f[c].c_str(), &end);
      if (f[c].empty() || end != f[c].c_str() + f[c].size())
        throw topos::data::DataError(source + ":" + std::to_string(n) + ": column " + t.columns[c] +
                                     ": '" + f[c] + "' is not a number");
      row.push_back(v);
    }
    t.rows.push_back(std::move(row));
  }
  if (header.empty()) throw topos::data::DataError(source + ": empty (no header row)");
  return t;
}

/// What `hopnet train` logs: one row per optimizer step, one per epoch.
struct TrainingLog {
  std::filesystem::path folder;
  std::vector<double> step, step_epoch, step_loss;      // steps.csv
  std::vector<double> epoch, train_loss, val_loss, lr;  // epochs.csv
  /// epochs.csv's validation rollouts (position RMSE at the run's frame), where it has them.
  std::vector<double> val_rollout;
};

/// Reads `folder`/steps.csv and `folder`/epochs.csv (either may be missing, not both).
inline TrainingLog read_training_log(const std::filesystem::path& folder) {
  TrainingLog log;
  log.folder = folder;
  const auto steps = folder / "steps.csv", epochs = folder / "epochs.csv";
  if (!std::filesystem::exists(steps) && !std::filesystem::exists(epochs))
    throw topos::data::DataError(
        folder.string() + ": no training log (steps.csv or epochs.csv, as hopnet train writes)");
  if (std::filesystem::exists(steps)) {
    const auto t = read_csv_numbers(steps);
    log.step = t.column("step", steps.string());
    log.step_epoch = t.column("epoch", steps.string());
    log.step_loss = t.column("loss", steps.string());
  }
  if (std::filesystem::exists(epochs)) {
    const auto t = read_csv_numbers(epochs);
    log.epoch = t.column("epoch", epochs.string());
    log.train_loss = t.column("train_loss", epochs.string());
    log.val_loss = t.column("val_loss", epochs.string());
    log.lr = t.column("lr", epochs.string());
    if (t.has("val_rollout_pos_rmse"))
      log.val_rollout = t.column("val_rollout_pos_rmse", epochs.string());
  }
  return log;
}

/// Numbers for JSON: NaN and infinities become null (JSON has neither).
inline nlohmann::json numbers(const std::vector<double>& v) {
  nlohmann::json a = nlohmann::json::array();
  for (double x : v) a.push_back(std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(nullptr));
  return a;
}

inline nlohmann::json training_json(const TrainingLog& log) {
  return {{"folder", log.folder.string()},
          {"step", numbers(log.step)},
          {"step_epoch", numbers(log.step_epoch)},
          {"step_loss", numbers(log.step_loss)},
          {"epoch", numbers(log.epoch)},
          {"train_loss", numbers(log.train_loss)},
          {"val_loss", numbers(log.val_loss)},
          {"lr", numbers(log.lr)},
          {"val_rollout", numbers(log.val_rollout)}};
}

// ---- the paper's results and the dataset kind -------------------------------------------------

/// One row of the paper's supplementary tables: mean ± std over three training seeds at frames
/// 25, 50, 75, 100 (the paper's Tables 4-11, docs/reproduction.md). The orientation figures are
/// printed as RMSE but are probably the MAE (docs/reproduction.md), so the report sets them
/// beside ori_mae.
struct PaperRow {
  std::string kind, label;
  std::array<double, 4> pos, pos_std, ori, ori_std;
};

/// The paper's rows for one dataset kind: HOPNet's at every horizon, then the baselines it
/// quotes from the FIGNet paper (supplementary Tables 4 and 5), which have frame 50 only (NaN
/// elsewhere).
inline const std::vector<PaperRow>& paper_rows() {
  const double n = std::nan("");
  static const std::vector<PaperRow> rows{{"movi-a",
                                           "HOPNet paper, MOVi-A (Table 4)",
                                           {0.014, 0.054, 0.115, 0.196},
                                           {1e-4, 1e-4, 0.002, 0.003},
                                           {1.634, 5.641, 11.842, 18.828},
                                           {0.047, 0.222, 0.371, 0.489}},
                                          {"movi-b",
                                           "HOPNet paper, MOVi-B (Table 5)",
                                           {0.010, 0.047, 0.101, 0.176},
                                           {1e-4, 0.001, 0.003, 0.007},
                                           {1.064, 4.911, 10.350, 17.912},
                                           {0.013, 0.004, 0.032, 0.123}},
                                          {"movi-spheres",
                                           "HOPNet paper, MOVi-spheres (Table 6)",
                                           {0.007, 0.034, 0.073, 0.124},
                                           {1e-4, 1e-4, 0.002, 0.005},
                                           {0.913, 4.051, 8.212, 13.675},
                                           {0.018, 0.078, 0.200, 0.317}},
                                          {"movi-a",
                                           "FIGNet, quoted by the paper (MOVi-A)",
                                           {n, 0.115, n, n},
                                           {n, 0.008, n, n},
                                           {n, 14.837, n, n},
                                           {n, 0.175, n, n}},
                                          {"movi-a",
                                           "MGN-LargeRadius, quoted by the paper (MOVi-A)",
                                           {n, 0.119, n, n},
                                           {n, 0.009, n, n},
                                           {n, 15.069, n, n},
                                           {n, 0.649, n, n}},
                                          {"movi-a",
                                           "MGN, quoted by the paper (MOVi-A)",
                                           {n, 0.705, n, n},
                                           {n, 0.069, n, n},
                                           {n, 31.210, n, n},
                                           {n, 0.989, n, n}},
                                          {"movi-b",
                                           "FIGNet, quoted by the paper (MOVi-B)",
                                           {n, 0.127, n, n},
                                           {n, 0.006, n, n},
                                           {n, 13.990, n, n},
                                           {n, 0.464, n, n}},
                                          {"movi-b",
                                           "MGN-LargeRadius, quoted by the paper (MOVi-B)",
                                           {n, 0.460, n, n},
                                           {n, 0.045, n, n},
                                           {n, 26.342, n, n},
                                           {n, 1.397, n, n}},
                                          {"movi-b",
                                           "MGN, quoted by the paper (MOVi-B)",
                                           {n, 0.538, n, n},
                                           {n, 0.035, n, n},
                                           {n, 26.914, n, n},
                                           {n, 0.783, n, n}}};
  return rows;
}

/// The MOVi kind the scenes were drawn from, by the generator's rules
/// (topos/data/movi_generator.hpp): spheres has only spheres and A only cubes, cylinders and
/// spheres, both of size 0.7 or 1.4; B has the other KuBasic shapes or sizes in between. ""
/// when nothing fits (an asset outside KuBasic, a MOVi-C scene). `why` says what decided.
inline std::string infer_movi_kind(const std::vector<topos::data::KubricScene>& scenes,
                                   std::string* why = nullptr) {
  static const std::set<std::string> clevr{"cube", "cylinder", "sphere"};
  static const std::set<std::string> kubasic{"cube",  "cylinder", "sphere",     "cone",
                                             "torus", "gear",     "torus_knot", "sponge",
                                             "spot",  "teapot",   "suzanne"};
  bool only_spheres = true, only_clevr = true, two_sizes = true;
  std::size_t objects = 0;
  for (const auto& s : scenes)
    for (const auto& k : s.instances) {
      ++objects;
      if (!kubasic.count(k.shape)) {
        if (why) *why = "shape '" + k.shape + "' is not a KuBasic shape";
        return "";
      }
      if (k.size < 0.7 - 1e-5 || k.size > 1.4 + 1e-5) {
        if (why) *why = "size " + std::to_string(k.size) + " is outside MOVi's 0.7-1.4";
        return "";
      }
      only_spheres = only_spheres && k.shape == "sphere";
      only_clevr = only_clevr && clevr.count(k.shape);
      two_sizes = two_sizes && (std::abs(k.size - 0.7) < 1e-5 || std::abs(k.size - 1.4) < 1e-5);
    }
  const std::string n = std::to_string(objects) + " objects";
  if (objects == 0) {
    if (why) *why = "no objects";
    return "";
  }
  if (!only_clevr || !two_sizes) {
    if (why)
      *why = n + (only_clevr ? ": sizes between 0.7 and 1.4"
                             : ": KuBasic shapes beyond cube, cylinder and sphere");
    return "movi-b";
  }
  if (why)
    *why = n + (only_spheres ? ": only spheres of size 0.7 or 1.4"
                             : ": cubes, cylinders and spheres of size 0.7 or 1.4");
  return only_spheres ? "movi-spheres" : "movi-a";
}

// ---- the evaluation report --------------------------------------------------------------------

struct SceneResult {
  std::int64_t seed = 0;
  int objects = 0;
  std::vector<topos::sim::RolloutMetrics> models;  ///< per model (model_names' order)
  topos::sim::RolloutMetrics baseline;             ///< constant velocity
  int viewer_index = -1;  ///< its place in viewer.html, -1 when not shown there
};

struct EvaluationReport {
  std::string title, checkpoint, data, split, mode,
      viewer;                                  ///< viewer: file name beside index.html, or ""
  std::string dataset_kind, dataset_kind_why;  ///< infer_movi_kind
  std::vector<int> horizons{25, 50, 75, 100};
  std::vector<std::string> model_names{"topos"};  ///< the checkpoints' models, in order
  std::vector<SceneResult> scenes;
  double rollout_seconds = 0;
  std::optional<TrainingLog> training;  ///< the checkpoint folder's logs, when it has them
  std::string training_note;            ///< why they are not shown, when they are not
  /// metrics.json's `models` (per model, horizon and metric: mean, std, ci95) and `paired` (each
  /// later model against the first: ratio, ci95); the page shows them where they are objects.
  nlohmann::json intervals, paired;
};

/// Mean and (population) std over the scenes at every frame, skipping NaN; n counts the scenes.
struct FrameStats {
  std::vector<double> mean, std, n;
};

inline FrameStats frame_stats(const std::vector<const std::vector<double>*>& curves) {
  std::size_t frames = 0;
  for (const auto* c : curves) frames = std::max(frames, c->size());
  FrameStats s;
  for (std::size_t f = 0; f < frames; ++f) {
    double sum = 0, sq = 0;
    int n = 0;
    for (const auto* c : curves)
      if (f < c->size() && std::isfinite((*c)[f])) sum += (*c)[f], ++n;
    const double m = n ? sum / n : std::nan("");
    for (const auto* c : curves)
      if (f < c->size() && std::isfinite((*c)[f])) sq += ((*c)[f] - m) * ((*c)[f] - m);
    s.mean.push_back(m);
    s.std.push_back(n ? std::sqrt(sq / n) : std::nan(""));
    s.n.push_back(n);
  }
  return s;
}

inline nlohmann::json evaluation_json(const EvaluationReport& r) {
  using RM = topos::sim::RolloutMetrics;
  nlohmann::json models = nlohmann::json::object();
  std::vector<std::pair<std::string, std::function<const RM&(const SceneResult&)>>> picks;
  for (std::size_t k = 0; k < r.model_names.size(); ++k)
    picks.emplace_back(r.model_names[k],
                       [k](const SceneResult& s) -> const RM& { return s.models.at(k); });
  picks.emplace_back("constant_velocity",
                     [](const SceneResult& s) -> const RM& { return s.baseline; });
  nlohmann::json order = nlohmann::json::array();
  for (const auto& [model, pick] : picks) {
    order.push_back(model);
    for (const auto& [metric, member] :
         std::vector<std::pair<std::string, std::vector<double> RM::*>>{
             {"pos_rmse", &RM::pos_rmse},
             {"pos_mae", &RM::pos_mae},
             {"ori_rmse", &RM::ori_rmse},
             {"ori_mae", &RM::ori_mae}}) {
      std::vector<const std::vector<double>*> curves;
      for (const auto& s : r.scenes) curves.push_back(&(pick(s).*member));
      const auto st = frame_stats(curves);
      models[model][metric] = {{"mean", numbers(st.mean)}, {"std", numbers(st.std)}, {"n", st.n}};
    }
  }
  nlohmann::json scenes = nlohmann::json::array();
  for (const auto& s : r.scenes) {
    nlohmann::json at = nlohmann::json::object();
    for (int h : r.horizons) {
      const auto u = static_cast<std::size_t>(h);
      const auto get = [&](const std::vector<double>& v) {
        return u < v.size() && std::isfinite(v[u]) ? nlohmann::json(v[u]) : nlohmann::json(nullptr);
      };
      at[std::to_string(h)] = {{"pos_rmse", get(s.models.front().pos_rmse)},
                               {"ori_mae", get(s.models.front().ori_mae)},
                               {"cv_pos_rmse", get(s.baseline.pos_rmse)}};
    }
    scenes.push_back(
        {{"seed", s.seed}, {"objects", s.objects}, {"viewer_index", s.viewer_index}, {"at", at}});
  }
  nlohmann::json paper = nlohmann::json::array();
  const auto vec = [](const std::array<double, 4>& a) {
    return numbers(std::vector<double>(a.begin(), a.end()));
  };
  for (const auto& p : paper_rows())
    if (p.kind == r.dataset_kind)
      paper.push_back({{"label", p.label},
                       {"frames", {25, 50, 75, 100}},
                       {"pos_rmse", {{"mean", vec(p.pos)}, {"std", vec(p.pos_std)}}},
                       {"ori_mae", {{"mean", vec(p.ori)}, {"std", vec(p.ori_std)}}}});
  return {{"checkpoint", r.checkpoint},
          {"data", r.data},
          {"split", r.split},
          {"mode", r.mode},
          {"viewer", r.viewer},
          {"dataset_kind", r.dataset_kind},
          {"dataset_kind_why", r.dataset_kind_why},
          {"horizons", r.horizons},
          {"models", models},
          {"model_order", order},
          {"scenes", scenes},
          {"paper", paper},
          {"intervals", r.intervals.is_object() ? r.intervals : nlohmann::json::object()},
          {"paired", r.paired.is_object() ? r.paired : nlohmann::json::object()},
          {"rollout_seconds", r.rollout_seconds}};
}

/// The report page: `evaluation` and `training` are each JSON or null (see evaluation_json,
/// training_json); the page shows what it is given.
inline std::string report_html(const std::string& title, const nlohmann::json& evaluation,
                               const nlohmann::json& training, const std::string& note = "") {
  const nlohmann::json data{
      {"title", title}, {"evaluation", evaluation}, {"training", training}, {"note", note}};
  return hopnet_web::fill_template(
      hopnet_web::templates::report_html,
      {{"CHARTJS", hopnet_web::chart_js_script()}, {"DATA", hopnet_web::script_json(data)}},
      "report");
}

/// Writes index.html for an evaluation (atomically).
inline void write_evaluation_report(const std::string& path, const EvaluationReport& r) {
  topos::io::write_file_atomic(
      path, report_html(r.title, evaluation_json(r),
                        r.training ? training_json(*r.training) : nullptr, r.training_note));
}

/// Writes the training curves of `log` (atomically).
inline void write_training_report(const std::string& path, const TrainingLog& log) {
  topos::io::write_file_atomic(
      path, report_html("HOPNet training: " + log.folder.string(), nullptr, training_json(log)));
}

}  // namespace hopnet_report
