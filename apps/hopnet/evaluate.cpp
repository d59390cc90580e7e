// hopnet evaluate: roll out every scene of a split with one or several checkpoints (HOPNet's and
// the baselines'); the paper's table beside a constant-velocity baseline and the paper's rows.
#include "commands.hpp"
#include "report.hpp"
#include "topos/nn/device.hpp"
#include "topos/util/bootstrap.hpp"
#include "viewer.hpp"

#include <algorithm>
#include <atomic>
#include <map>
#include <mutex>
#include <optional>
#include <thread>

namespace hopnet_cli {
namespace {

// ---- evaluate ---------------------------------------------------------------------------------
struct EvaluateArgs {
  std::vector<std::string> checkpoints, stats, names;
  std::string data, assets, split = "test", split_file, mode = "reference", out, device = "cpu",
                            matmul_precision = "highest", cpu_gemm = "auto";
  int steps = 102, viewer_scenes = 6, jobs = 0;
  VariantArgs variant;
  bool no_report = false;
};

// Constant velocity: positions and rotations keep their last per-frame change.
std::vector<Poses> constant_velocity(const Scene& s, int frames) {
  std::vector<Poses> p;
  for (int t = 0; t < 4; ++t) p.push_back(scene_poses(s, t));
  while (static_cast<int>(p.size()) < frames) {
    const auto& a = p[p.size() - 2];
    const auto& b = p.back();
    Poses n = b;
    for (Eigen::Index o = 0; o < n.positions.rows(); ++o) {
      n.positions.row(o) = 2 * b.positions.row(o) - a.positions.row(o);
      const Eigen::Quaterniond qa(a.quaternions(o, 0), a.quaternions(o, 1), a.quaternions(o, 2),
                                  a.quaternions(o, 3));
      const Eigen::Quaterniond qb(b.quaternions(o, 0), b.quaternions(o, 1), b.quaternions(o, 2),
                                  b.quaternions(o, 3));
      const Eigen::Quaterniond qn = (qb * qa.inverse() * qb).normalized();
      n.quaternions.row(o) << qn.w(), qn.x(), qn.y(), qn.z();
    }
    p.push_back(n);
  }
  return p;
}

int run_evaluate(const EvaluateArgs& a) {
  namespace fs = std::filesystem;
  const FeatureMode mode = feature_mode_from_string(a.mode);
  set_rollout_precision(a.matmul_precision, mode);  // every worker's rollouts
  const std::string gemm = set_rollout_gemm(a.cpu_gemm, mode);
  const torch::Device device = nn::device_from_string(a.device);
  // Every checkpoint is read and checked once here (sim::open_model); each worker thread below
  // rolls out with its own copy of each model (Simulator::clone), on --device.
  struct Model {
    std::string name, variant, checkpoint;
    sim::OpenedModel opened;
  };
  if (a.stats.size() > 1 && a.stats.size() != a.checkpoints.size())
    throw std::invalid_argument(
        "--stats: " + std::to_string(a.stats.size()) + " files for " +
        std::to_string(a.checkpoints.size()) +
        " checkpoints; give one for every checkpoint, or one per --checkpoint in its order ('-' "
        "for a baseline's)");
  if (!a.names.empty() && a.names.size() != a.checkpoints.size())
    throw std::invalid_argument("--name: " + std::to_string(a.names.size()) + " names for " +
                                std::to_string(a.checkpoints.size()) +
                                " checkpoints; give one per --checkpoint, in its order");
  std::vector<Model> models;
  for (std::size_t k = 0; k < a.checkpoints.size(); ++k) {
    const std::string& path = a.checkpoints[k];
    const bool own_stats = a.stats.size() > 1;  // the k-th file goes with the k-th checkpoint
    std::string stats = a.stats.empty() ? "" : a.stats[own_stats ? k : 0];
    const bool dash = stats == "-";  // a baseline's: its statistics are in its checkpoint
    if (dash) stats.clear();
    Model m;
    m.checkpoint = path;
    auto how = open_options(a.variant, stats, mode);
    how.require_statistics = !dash;  // said below, by the --stats entry's position
    m.opened = open_checkpoint(path, how);
    const bool hopnet = dynamic_cast<HopnetSimulator*>(m.opened.simulator.get()) != nullptr;
    if (dash && hopnet)
      throw std::invalid_argument(
          "--stats: '-' goes with " + path +
          ", a HOPNet checkpoint, which needs its normalisation statistics: write its stats.json "
          "there (hopnet train writes one beside its checkpoints)");
    if (own_stats && !stats.empty() && !hopnet)
      throw std::invalid_argument("--stats " + stats + " goes with " + path + ", a " +
                                  m.opened.simulator->name() +
                                  " checkpoint, which holds its own statistics; write '-' there");
    m.name = m.opened.simulator->name();
    m.variant = m.opened.simulator->variant();
    if (!a.names.empty()) {
      m.name = a.names[k];
      const bool taken = std::any_of(models.begin(), models.end(),
                                     [&](const Model& other) { return other.name == m.name; });
      if (taken || m.name == "constant_velocity" || m.name.empty())
        throw std::invalid_argument("--name '" + m.name + "' (for " + path +
                                    "): each checkpoint needs a name of its own, not empty "
                                    "and not 'constant_velocity'");
    }
    // Two checkpoints of one model: their variants tell them apart, then their order.
    for (const auto& other : models)
      if (other.name == m.name) m.name += " (" + m.variant + ", " + path + ")";
    models.push_back(std::move(m));
  }
  const std::string model_name = models.front().name;
  const auto dataset = data::Dataset::open(a.data);
  const auto& ids = dataset.ids();
  const auto chosen = data::split_part(
      a.split_file.empty() ? data::reference_split(ids) : data::read_split_json(a.split_file),
      a.split, ids);
  if (chosen.empty()) throw data::DataError(a.data + ": the " + a.split + " split is empty");
  if (!a.no_report) hopnet_web::require_js_libraries();  // before hours of rollouts, not after
  fs::create_directories(a.out);
  const std::vector<int> horizons{25, 50, 75, 100};
  std::map<std::string, std::map<int, std::vector<double>>>
      per;  // "model.pos_rmse" -> frame -> values
  ProgressBar bar("evaluate", static_cast<std::int64_t>(chosen.size()), "scenes");
  double seconds = 0;
  // Scenes are rolled out by `jobs` threads, each with its own model (one intra-op thread each).
  struct Result {
    std::optional<Scene> scene;  // kept for the viewer
    std::vector<Poses> poses;
    std::vector<RolloutMetrics> models;  // in --checkpoint order; the viewer shows the first's
    RolloutMetrics baseline;
    double seconds = 0;
    int objects = 0;  // dynamic ones, those the metrics average over
  };
  std::vector<Result> results(chosen.size());
  std::atomic<std::size_t> next{0};
  std::atomic<bool> failed{false};
  std::mutex mutex;  // guards the progress bar and `error`
  std::string error;
  const auto work = [&] {
    try {
      std::vector<std::unique_ptr<sim::Simulator>> own;
      for (const auto& m : models) {
        own.push_back(m.opened.simulator->clone());
        own.back()->to(device);
      }
      MeshLibrary lib(a.assets);
      for (std::size_t i = next++; i < chosen.size() && !failed; i = next++) {
        Scene scene = make_scene(dataset.scene(chosen[i]), lib);
        RolloutOptions opt;
        opt.steps = static_cast<int>(std::min<std::int64_t>(a.steps, scene.num_frames - 4));
        auto& out = results[i];
        std::vector<Poses> first;
        for (auto& model : own) {
          auto r = sim::rollout(*model, scene, opt);
          out.models.push_back(rollout_metrics(r.poses, scene));
          out.seconds += r.seconds;
          if (first.empty()) first = std::move(r.poses);
        }
        out.baseline =
            rollout_metrics(constant_velocity(scene, static_cast<int>(first.size())), scene);
        for (const auto& o : scene.objects) out.objects += !o.is_floor;
        if (static_cast<int>(i) < a.viewer_scenes)
          out.scene = std::move(scene), out.poses = std::move(first);
        std::lock_guard<std::mutex> lock(mutex);
        bar.update(1, "scene " + std::to_string(chosen[i]));
      }
    } catch (const std::exception& e) {
      std::lock_guard<std::mutex> lock(mutex);
      if (!failed.exchange(true)) error = e.what();
    }
  };
  const int jobs = std::max(
      1, std::min<int>(a.jobs > 0 ? a.jobs : static_cast<int>(std::thread::hardware_concurrency()),
                       static_cast<int>(chosen.size())));
  std::vector<std::thread> pool;
  for (int j = 0; j < jobs; ++j) pool.emplace_back(work);
  for (auto& t : pool) t.join();
  if (failed) throw std::runtime_error(error);
  std::vector<hopnet_viewer::ViewerScene> viewer;
  for (std::size_t i = 0; i < chosen.size(); ++i) {
    const auto& res = results[i];
    seconds += res.seconds;
    std::vector<std::pair<std::string, const RolloutMetrics*>> rows;
    for (std::size_t k = 0; k < models.size(); ++k)
      rows.emplace_back(models[k].name, &res.models[k]);
    rows.emplace_back("constant_velocity", &res.baseline);
    for (const auto& [name, m] : rows) {
      for (int h : horizons) {
        if (h >= static_cast<int>(m->pos_rmse.size())) continue;
        per[name + ".pos_rmse"][h].push_back(m->pos_rmse[static_cast<std::size_t>(h)]);
        per[name + ".ori_rmse"][h].push_back(m->ori_rmse[static_cast<std::size_t>(h)]);
        per[name + ".ori_mae"][h].push_back(m->ori_mae[static_cast<std::size_t>(h)]);
      }
    }
    if (res.scene)
      viewer.push_back({"scene " + std::to_string(chosen[i]),
                        &*res.scene,
                        res.poses,
                        {{"prediction", res.models.front().pos_rmse},
                         {"constant velocity", res.baseline.pos_rmse}}});
  }
  bar.finish();
  const auto stat = [](const std::vector<double>& v) {
    double m = 0, s = 0;
    int n = 0;
    for (double x : v)
      if (std::isfinite(x)) m += x, ++n;
    m = n ? m / n : NAN;
    for (double x : v)
      if (std::isfinite(x)) s += (x - m) * (x - m);
    return std::pair<double, double>{m, n ? std::sqrt(s / n) : NAN};
  };
  // The dataset kind decides which of the paper's rows stand beside ours.
  std::vector<data::KubricScene> sources;
  for (auto id : chosen) sources.push_back(dataset.scene(id));
  std::string kind_why;
  const std::string kind = hopnet_report::infer_movi_kind(sources, &kind_why);
  nlohmann::json metrics;
  std::ostringstream md;
  std::vector<int> present;
  for (int h : horizons)
    if (per[model_name + ".pos_rmse"].count(h)) present.push_back(h);
  // A table's head (after its title, where it has one): model, metric, the frames present.
  const auto header = [&](const std::string& title) {
    if (!title.empty()) md << "\n" << title << "\n\n";
    md << "| model | metric | ";
    for (int h : present) md << "frame " << h << " | ";
    md << "\n|---|---|";
    for (std::size_t i = 0; i < present.size(); ++i) md << "---|";
    md << "\n";
  };
  header("");
  // The means' 95 % intervals: percentile bootstrap over the scenes, fixed seed.
  topos::BootstrapOptions bootstrap;
  bootstrap.resamples = 2000;
  std::vector<std::string> names;
  for (const auto& m : models) names.push_back(m.name);
  names.push_back("constant_velocity");
  for (const std::string& model : names) {
    for (const char* metric : {"pos_rmse", "ori_rmse", "ori_mae"}) {
      md << "| " << model << " | " << metric << (metric[0] == 'p' ? " (m)" : " (deg)") << " | ";
      for (int h : present) {
        const auto [m, s] = stat(per[model + "." + metric][h]);
        const auto ci = topos::bootstrap_mean(per[model + "." + metric][h], bootstrap);
        metrics[model][std::to_string(h)][metric] = {
            {"mean", m}, {"std", s}, {"ci95", {ci.low, ci.high}}};
        char buf[64];
        std::snprintf(buf, sizeof buf, metric[0] == 'p' ? "%.4f ± %.4f" : "%.2f ± %.2f", m, s);
        md << buf << " | ";
      }
      md << "\n";
    }
  }  // The paper's rows (quoted: mean ± std over its three seeds; "–" where it gives none).
  for (const auto& p : hopnet_report::paper_rows()) {
    if (p.kind != kind) continue;
    for (const auto& [metric, mean, sd] :
         {std::tuple<const char*, const std::array<double, 4>*, const std::array<double, 4>*>{
              "pos_rmse (m)", &p.pos, &p.pos_std},
          {"ori_mae (deg)", &p.ori, &p.ori_std}}) {
      md << "| " << p.label << " | " << metric << " | ";
      for (int h : present) {
        const auto k = static_cast<std::size_t>(h / 25 - 1);  // frames 25, 50, 75, 100
        char buf[64];
        if (h % 25 != 0 || k > 3 || !std::isfinite((*mean)[k]))
          std::snprintf(buf, sizeof buf, "–");
        else
          std::snprintf(buf, sizeof buf, metric[0] == 'p' ? "%.4f ± %.4f" : "%.2f ± %.2f",
                        (*mean)[k], (*sd)[k]);
        md << buf << " | ";
      }
      md << "\n";
    }
  }

  // The means' intervals, and each later checkpoint against the first on the same scenes: the
  // ratio of their means, its interval from resampling the scenes for both at once (what the
  // scenes share cancels, so a 5 % difference shows where the two unpaired intervals overlap).
  header("95 % intervals of the means (percentile bootstrap over the " +
         std::to_string(chosen.size()) + " scenes, 2,000 resamples):");
  for (const std::string& model : names)
    for (const char* metric : {"pos_rmse", "ori_rmse", "ori_mae"}) {
      md << "| " << model << " | " << metric << " | ";
      for (int h : present) {
        const auto& m = metrics[model][std::to_string(h)][metric];
        char buf[96];
        std::snprintf(buf, sizeof buf, metric[0] == 'p' ? "%.4f [%.4f, %.4f]" : "%.2f [%.2f, %.2f]",
                      m["mean"].get<double>(), m["ci95"][0].get<double>(),
                      m["ci95"][1].get<double>());
        md << buf << " | ";
      }
      md << "\n";
    }
  nlohmann::json paired = nlohmann::json::object();
  if (models.size() > 1) {
    header("Against " + names.front() +
           " on the same scenes: the ratio of the means, its paired 95 % interval:");
    for (std::size_t k = 1; k < models.size(); ++k)
      for (const char* metric : {"pos_rmse", "ori_rmse", "ori_mae"}) {
        md << "| " << names[k] << " / " << names.front() << " | " << metric << " | ";
        for (int h : present) {
          const auto r = topos::bootstrap_ratio_of_means(
              per[names[k] + "." + metric][h], per[names.front() + "." + metric][h], bootstrap);
          paired[names[k]]["against"] = names.front();
          paired[names[k]][std::to_string(h)][metric] = {{"ratio", r.estimate},
                                                         {"ci95", {r.low, r.high}}};
          char buf[96];
          std::snprintf(buf, sizeof buf, "%.3f [%.3f, %.3f]", r.estimate, r.low, r.high);
          md << buf << " | ";
        }
        md << "\n";
      }
  }

  // The layout: metrics.json holds, per frame, mean/std of pos_rmse, ori_rmse, ori_mae (the
  // model's).
  std::string label = model_name == "hopnet" ? "HOPNet" : model_name;
  for (std::size_t k = 1; k < models.size(); ++k) label += ", " + models[k].name;
  nlohmann::json top = metrics[model_name];
  top["baseline_constant_velocity"] = metrics["constant_velocity"];
  top["scenes"] = chosen;
  top["mode"] = to_string(mode);
  top["matmul_precision"] = a.matmul_precision;
  const std::string kernels = precision_label(a.matmul_precision, device.is_cpu());
  top["matmul_kernels"] = kernels;
  top["cpu_gemm"] = gemm;
  top["model"] = model_name;
  top["variant"] = models.front().variant;
  top["models"] = metrics;  // every checkpoint's and constant velocity's, by name
  top["model_order"] = names;
  if (!paired.empty()) top["paired"] = paired;  // every later checkpoint against the first
  // Per scene (in top["scenes"] order), every frame: for other statistics than the mean over
  // scenes (bootstrap intervals, subsets, pooling; scripts/reproduction_table.py).
  nlohmann::json per_scene = nlohmann::json::array();
  for (const auto& res : results) {
    const auto& first = res.models.front();
    nlohmann::json each = nlohmann::json::object();
    for (std::size_t k = 0; k < models.size(); ++k)
      each[models[k].name] = {{"pos_rmse", res.models[k].pos_rmse},
                              {"ori_rmse", res.models[k].ori_rmse},
                              {"ori_mae", res.models[k].ori_mae}};
    per_scene.push_back({{"pos_rmse", first.pos_rmse},
                         {"pos_mae", first.pos_mae},
                         {"ori_rmse", first.ori_rmse},
                         {"ori_mae", first.ori_mae},
                         {"cv_pos_rmse", res.baseline.pos_rmse},
                         {"cv_ori_rmse", res.baseline.ori_rmse},
                         {"models", each},
                         {"objects", res.objects}});
  }
  top["rollout_seconds"] = seconds;
  write_json_atomic(top, (fs::path(a.out) / "metrics.json").string());
  write_json_atomic({{"scenes", chosen}, {"per_scene", per_scene}},
                    (fs::path(a.out) / "per_scene.json").string());
  {
    std::ostringstream t;
    t << "# " << label << " rollout errors (" << chosen.size() << " scenes, " << a.split
      << " split, " << to_string(mode) << " mode"
      << (a.matmul_precision == "highest" ? "" : ", matmul precision " + kernels) << ")\n\n"
      << md.str();
    io::write_file_atomic((fs::path(a.out) / "table.md").string(), t.str());
  }
  const std::string title =
      label + " rollouts (" + std::string(to_string(mode)) + " mode): " + a.data;
  if (!a.no_report) {
    if (!viewer.empty())
      hopnet_viewer::write_viewer_html((fs::path(a.out) / "viewer.html").string(), title, viewer);
    hopnet_report::EvaluationReport report;
    report.title = title;
    for (const auto& m : models)
      report.checkpoint += (report.checkpoint.empty() ? "" : ", ") + m.checkpoint;
    report.data = a.data, report.split = a.split, report.mode = to_string(mode);
    report.model_names = names;
    report.model_names.pop_back();  // constant velocity is the report's own row
    report.viewer = viewer.empty() ? "" : "viewer.html";
    report.horizons = horizons;
    report.rollout_seconds = seconds;
    report.intervals = metrics, report.paired = paired;
    for (std::size_t i = 0; i < chosen.size(); ++i)
      report.scenes.push_back({chosen[i], static_cast<int>(sources[i].instances.size()),
                               results[i].models, results[i].baseline,
                               static_cast<int>(i) < a.viewer_scenes ? static_cast<int>(i) : -1});
    report.dataset_kind = kind, report.dataset_kind_why = kind_why;
    // The training curves too, of the first checkpoint that sits beside its training logs (a
    // published model first, the one trained here after it).
    std::optional<fs::path> log_dir;
    for (const auto& m : models) {
      const auto dir = fs::path(m.checkpoint).parent_path();
      if (!log_dir && (fs::exists(dir / "steps.csv") || fs::exists(dir / "epochs.csv")))
        log_dir = dir;
    }
    if (log_dir) {
      try {
        report.training = hopnet_report::read_training_log(*log_dir);
      } catch (const data::DataError& e) {
        report.training_note = std::string("training curves not shown: ") + e.what();
      }
    }
    hopnet_report::write_evaluation_report((fs::path(a.out) / "index.html").string(), report);
  }
  std::cout << md.str() << "wrote " << a.out << "/metrics.json, table.md"
            << (a.no_report ? "" : ", index.html")
            << (a.no_report || viewer.empty() ? "" : ", viewer.html") << "\n";
  return 0;
}

}  // namespace

Command add_evaluate(CLI::App& app) {
  auto args = std::make_shared<EvaluateArgs>();
  auto& ev = *args;
  auto* ce = app.add_subcommand(
      "evaluate",
      "roll out every scene of a split; the paper's table beside a constant-velocity baseline");
  ce->add_option("--checkpoint", ev.checkpoints,
                 "model checkpoint (HOPNet's or a baseline's); several, repeated or listed, give "
                 "one table and one set of curves with every model's rows")
      ->required()
      ->check(CLI::ExistingFile);
  ce->add_option("--stats", ev.stats,
                 "normalisation statistics (HOPNet's; a baseline's are in its checkpoint): one "
                 "file for every checkpoint, or one per --checkpoint in its order ('-' for a "
                 "baseline's)")
      ->check(CLI::ExistingFile | CLI::IsMember({"-"}));
  ce->add_option("--name", ev.names,
                 "the checkpoints' names in the table and the report, one per --checkpoint in its "
                 "order (default: the model's, e.g. hopnet, with variant and path where two "
                 "share it)");
  ce->add_option("--data", ev.data, "dataset folder")->required()->check(CLI::ExistingDirectory);
  ce->add_option("--assets", ev.assets,
                 "KuBasic-layout asset folder (built-in shapes when omitted)");
  ce->add_option("--split", ev.split, "train, val, test or all")->capture_default_str();
  ce->add_option(
        "--split-file", ev.split_file,
        "custom split JSON {train, val, test} (default: the reference split of the scenes present)")
      ->check(CLI::ExistingFile);
  ce->add_option("--mode", ev.mode, "reference or native")->capture_default_str();
  add_rollout_precision_option(ce, ev.matmul_precision);
  add_rollout_gemm_option(ce, ev.cpu_gemm);
  ce->add_option("--steps", ev.steps, "rollout steps")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  ce->add_option("--jobs", ev.jobs, "scenes rolled out at once (default: all cores)");
  ce->add_option("--device", ev.device, "cpu, cuda, cuda:N or auto (each job's model runs there)")
      ->capture_default_str();
  ce->add_option("--viewer-scenes", ev.viewer_scenes, "scenes shown in viewer.html (0: no viewer)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  add_variant_options(ce, ev.variant, false);
  ce->add_flag("--no-report", ev.no_report,
               "write metrics.json, per_scene.json and table.md only: no index.html, no "
               "viewer.html (no JavaScript libraries needed)");
  ce->add_option("--out", ev.out,
                 "output folder: metrics.json, per_scene.json, table.md, index.html (the report: "
                 "tables, plots, training curves), viewer.html")
      ->required();
  return {ce, [args] { return run_evaluate(*args); }};
}

}  // namespace hopnet_cli
