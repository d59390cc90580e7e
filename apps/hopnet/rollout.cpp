// hopnet rollout: the autoregressive rollout of one scene with the paper's per-frame metrics.
#include "commands.hpp"
#include "topos/nn/device.hpp"
#include "viewer.hpp"

namespace hopnet_cli {
namespace {

struct RolloutArgs {
  std::string checkpoint, stats, scene, assets, mode = "reference", out, collisions, viewer,
                                                device = "cpu", matmul_precision = "highest",
                                                cpu_gemm = "auto";
  int steps = 102, step_threads = 1;
  bool no_collisions_json = false;
  VariantArgs variant;
};

int run_rollout(const RolloutArgs& a) {
  const FeatureMode mode = feature_mode_from_string(a.mode);
  set_rollout_precision(a.matmul_precision, mode);
  const std::string gemm = set_rollout_gemm(a.cpu_gemm, mode);
  if (!a.viewer.empty()) hopnet_web::require_js_libraries();
  MeshLibrary lib(a.assets);
  const auto kubric = data::read_kubric_metadata(a.scene);
  const Scene scene = make_scene(kubric, lib);
  if (scene.num_frames < a.steps + 4)
    std::cerr << "note: the scene has " << scene.num_frames << " frames; metrics cover the first "
              << scene.num_frames << "\n";
  const auto opened = open_checkpoint(a.checkpoint, open_options(a.variant, a.stats, mode));
  sim::Simulator& model = *opened.simulator;
  model.to(nn::device_from_string(a.device));
  model.step_threads(a.step_threads);
  const std::string variant = model.variant();
  RolloutOptions opt;
  opt.steps = a.steps;
  // Reference mode takes the first step's contacts from collisions.json beside the scene, as the
  // reference does (a model that detects no contacts ignores them).
  const std::string coll =
      a.collisions.empty() && mode == FeatureMode::reference && !a.no_collisions_json
          ? collisions_beside(kubric)
          : a.collisions;
  if (!coll.empty()) {
    const auto all = read_collisions_json(coll);
    auto it = all.find(3);
    if (it == all.end()) throw data::DataError(coll + ": has no frame 3");
    opt.first_contacts = it->second;
  }
  ProgressBar bar("rollout", opt.steps, "steps");
  opt.on_step = [&](int, int) { bar.update(); };
  const RolloutResult r = sim::rollout(model, scene, opt);
  bar.finish();
  const std::string kernels =
      precision_label(a.matmul_precision, nn::device_from_string(a.device).is_cpu());
  const auto m = rollout_metrics(r.poses, scene);
  nlohmann::json j;
  j["scene"] = kubric.source;
  j["mode"] = to_string(mode);
  j["matmul_precision"] = a.matmul_precision;
  j["matmul_kernels"] = kernels;
  j["cpu_gemm"] = gemm;
  j["step_threads"] = a.step_threads;
  j["checkpoint"] = a.checkpoint;
  j["variant"] = variant;
  j["frames"] = r.num_frames();
  j["pos_rmse"] = m.pos_rmse;
  j["pos_mae"] = m.pos_mae;
  j["ori_rmse"] = m.ori_rmse;
  j["ori_mae"] = m.ori_mae;
  j["invalid_ratio"] = r.invalid_ratio;
  j["seconds"] = r.seconds;
  nlohmann::json pos = nlohmann::json::array(), quat = nlohmann::json::array();
  for (const auto& p : r.poses) {
    nlohmann::json fp = nlohmann::json::array(), fq = nlohmann::json::array();
    for (std::size_t o = 0; o < scene.num_objects(); ++o) {
      if (scene.objects[o].is_floor) continue;
      const auto i = static_cast<Eigen::Index>(o);
      fp.push_back({p.positions(i, 0), p.positions(i, 1), p.positions(i, 2)});
      fq.push_back(
          {p.quaternions(i, 0), p.quaternions(i, 1), p.quaternions(i, 2), p.quaternions(i, 3)});
    }
    pos.push_back(fp);
    quat.push_back(fq);
  }
  j["positions"] = pos;
  j["quaternions"] = quat;
  write_json_atomic(j, a.out);
  if (!a.viewer.empty())
    hopnet_viewer::write_viewer_html(
        a.viewer,
        (model.name() == "hopnet" ? std::string("HOPNet") : model.name()) + " rollout (" +
            std::string(to_string(mode)) + " mode): " + kubric.source,
        {{kubric.source, &scene, r.poses, {{"prediction", m.pos_rmse}}}});
  std::printf(
      "rollout: %s, %d steps in %.3f s (%.2f ms/step), mode %s, matmul precision %s, cpu gemm "
      "%s\n",
      variant.c_str(), a.steps, r.seconds, 1e3 * r.seconds / a.steps, to_string(mode),
      kernels.c_str(), gemm.c_str());
  std::printf("%6s %10s %10s %10s %10s\n", "frame", "pos_rmse", "pos_mae", "ori_rmse", "ori_mae");
  for (int f : {4, 25, 50, 75, 100})
    if (f < static_cast<int>(m.pos_rmse.size()))
      std::printf("%6d %10.6f %10.6f %10.3f %10.3f\n", f, m.pos_rmse[static_cast<std::size_t>(f)],
                  m.pos_mae[static_cast<std::size_t>(f)], m.ori_rmse[static_cast<std::size_t>(f)],
                  m.ori_mae[static_cast<std::size_t>(f)]);
  std::printf("wrote %s\n", a.out.c_str());
  return 0;
}

}  // namespace

Command add_rollout(CLI::App& app) {
  auto args = std::make_shared<RolloutArgs>();
  auto& ro = *args;
  auto* cr = app.add_subcommand(
      "rollout", "autoregressive rollout of one scene with the paper's per-frame metrics");
  cr->add_option("--checkpoint", ro.checkpoint, "model checkpoint (topos or reference .pt)")
      ->required()
      ->check(CLI::ExistingFile);
  cr->add_option("--stats", ro.stats,
                 "normalisation statistics (JSON; HOPNet's: a baseline's are in its checkpoint)")
      ->check(CLI::ExistingFile);
  cr->add_option("--scene", ro.scene, "Kubric metadata.json, or the folder holding it")
      ->required()
      ->check(CLI::ExistingPath);
  cr->add_option("--assets", ro.assets,
                 "meshes in the KuBasic layout (<shape>/collision_geometry.obj); built-in shapes "
                 "when omitted");
  cr->add_option("--mode", ro.mode, "reference (the published model's inputs) or native")
      ->capture_default_str();
  add_rollout_precision_option(cr, ro.matmul_precision);
  add_rollout_gemm_option(cr, ro.cpu_gemm);
  cr->add_option("--steps", ro.steps, "frames to predict")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cr->add_option("--step-threads", ro.step_threads,
                 "threads that the network's independent steps share (the same poses; whether "
                 "2 pays depends on the machine: docs/benchmarks.md)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cr->add_option("--collisions", ro.collisions,
                 "collisions.json for the first step (default: beside the scene, reference mode)");
  cr->add_flag("--no-collisions-json", ro.no_collisions_json,
               "detect the first step's contacts too");
  cr->add_option("--out", ro.out, "output JSON")->required();
  add_variant_options(cr, ro.variant, false);
  cr->add_option("--device", ro.device,
                 "cpu, cuda, cuda:N or auto (one scene's small steps are fastest on the CPU)")
      ->capture_default_str();
  cr->add_option("--viewer", ro.viewer,
                 "also write the HTML viewer (prediction beside ground truth) here");
  return {cr, [args] { return run_rollout(*args); }};
}

}  // namespace hopnet_cli
