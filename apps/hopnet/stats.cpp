// hopnet stats: dataset statistics the paper quotes; here the number of contact cells X(3)
// (safe face pairs within d_c, reference-compatible detection) over every frame training uses.
#include "commands.hpp"

#include <atomic>
#include <mutex>
#include <thread>

namespace hopnet_cli {
namespace {

struct StatsArgs {
  std::string data, assets, mode = "reference", out;
  std::vector<double> radii{0.1};
  int jobs = 0;
};

int run_stats(const StatsArgs& a) {
  const FeatureMode mode = feature_mode_from_string(a.mode);
  for (double r : a.radii)
    if (!(r > 0) || !std::isfinite(r))
      throw std::invalid_argument("stats: a collision radius must be a positive number");
  const auto dataset = data::Dataset::open(a.data);
  const auto& ids = dataset.ids();
  if (ids.empty()) throw data::DataError(a.data + ": no scenes");
  const std::size_t R = a.radii.size();
  // Per scene and radius: cells over the frames training uses (the reference's t = 2..T-3, its
  // 476 timesteps for 480 frames), over topos's training frames (2..T-2) and over all frames.
  struct Count {
    std::vector<std::int64_t> training, topos_training, all;
    std::int64_t frames = 0;
  };
  std::vector<Count> counts(ids.size());
  std::atomic<std::size_t> next{0};
  std::atomic<bool> failed{false};
  std::mutex mutex;
  std::string error;
  ProgressBar bar("stats", static_cast<std::int64_t>(ids.size()), "scenes");
  const auto work = [&] {
    try {
      MeshLibrary lib(a.assets);
      for (std::size_t i = next++; i < ids.size() && !failed; i = next++) {
        const Scene scene = make_scene(dataset.scene(ids[i]), lib);
        const auto g = make_geometry(scene, mode);
        Count c{std::vector<std::int64_t>(R, 0), std::vector<std::int64_t>(R, 0),
                std::vector<std::int64_t>(R, 0), scene.num_frames};
        for (std::int64_t t = 0; t < scene.num_frames; ++t) {
          const auto posed = pose_objects(g, scene_poses(scene, t));
          for (std::size_t k = 0; k < R; ++k) {
            const auto n = count_contact_cells(g, posed, detect_contacts(g, posed, a.radii[k]));
            c.all[k] += n;
            if (t >= 2 && t <= scene.num_frames - 3) c.training[k] += n;
            if (t >= 2 && t <= scene.num_frames - 2) c.topos_training[k] += n;
          }
        }
        counts[i] = std::move(c);
        std::lock_guard<std::mutex> lock(mutex);
        bar.update(1, "scene " + std::to_string(ids[i]));
      }
    } catch (const std::exception& e) {
      std::lock_guard<std::mutex> lock(mutex);
      if (!failed.exchange(true)) error = e.what();
    }
  };
  const int jobs = std::max(
      1, std::min<int>(a.jobs > 0 ? a.jobs : static_cast<int>(std::thread::hardware_concurrency()),
                       static_cast<int>(ids.size())));
  std::vector<std::thread> pool;
  for (int j = 0; j < jobs; ++j) pool.emplace_back(work);
  for (auto& t : pool) t.join();
  if (failed) throw std::runtime_error(error);
  bar.finish();
  nlohmann::json j;
  j["data"] = a.data;
  j["scenes"] = ids.size();
  j["mode"] = to_string(mode);
  std::int64_t frames = 0;
  for (const auto& c : counts) frames += c.frames;
  j["frames"] = frames;
  std::printf("contact cells X(3) over %zu scenes (%lld frames), %s detection\n", ids.size(),
              static_cast<long long>(frames), to_string(mode));
  std::printf("%8s %18s %18s %18s\n", "d_c", "training frames", "t = 2..T-2", "all frames");
  for (std::size_t k = 0; k < R; ++k) {
    std::int64_t tr = 0, tt = 0, all = 0;
    std::vector<std::int64_t> per;
    for (const auto& c : counts)
      tr += c.training[k], tt += c.topos_training[k], all += c.all[k], per.push_back(c.training[k]);
    j["radii"].push_back({{"collision_radius", a.radii[k]},
                          {"training_frames", tr},
                          {"frames_2_to_T_minus_2", tt},
                          {"all_frames", all},
                          {"per_scene_training_frames", per}});
    std::printf("%8g %18lld %18lld %18lld\n", a.radii[k], static_cast<long long>(tr),
                static_cast<long long>(tt), static_cast<long long>(all));
  }
  j["ids"] = ids;
  j["note"] = "training frames: t = 2..T-3 (the reference's 476 timesteps of a 480-frame scene)";
  if (!a.out.empty()) {
    write_json_atomic(j, a.out);
    std::printf("wrote %s\n", a.out.c_str());
  }
  return 0;
}

}  // namespace

Command add_stats(CLI::App& app) {
  auto args = std::make_shared<StatsArgs>();
  auto& st = *args;
  auto* cs = app.add_subcommand("stats",
                                "count the contact cells X(3) of a dataset over the frames "
                                "training uses (the paper's Supplementary 3.6)");
  cs->add_option("--data", st.data, "dataset folder: topos format or Kubric scene folders")
      ->required()
      ->check(CLI::ExistingDirectory);
  cs->add_option("--assets", st.assets,
                 "KuBasic-layout asset folder (built-in shapes when omitted)");
  cs->add_option("--collision-radius", st.radii,
                 "contact distance d_c; several give one count each (0.05 0.1 0.2)")
      ->capture_default_str()
      ->expected(1, -1);
  cs->add_option(
        "--mode", st.mode,
        "reference (the reference's vertex-proximity detector) or native (exact face pairs)")
      ->capture_default_str();
  cs->add_option("--jobs", st.jobs, "scenes counted at once (default: all cores)");
  cs->add_option("--out", st.out, "also write the counts (totals and per scene) as JSON");
  return {cs, [args] { return run_stats(*args); }};
}

}  // namespace hopnet_cli
