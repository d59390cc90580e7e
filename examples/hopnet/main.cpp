// hopnet: the HOPNet program of topos. Subcommands: info, rollout (more with the trainer).
// Every subcommand has --help; errors print one line and exit with status 1.
#include "topos/core/progress.hpp"
#include "topos/data/dataset.hpp"
#include "topos/data/movi_generator.hpp"
#include "topos/models/hopnet/rollout.hpp"

#include <CLI/CLI.hpp>

#include <sys/wait.h>
#include <unistd.h>

#include <iostream>
#include <thread>

using namespace topos;
using namespace topos::hopnet;

namespace {

void write_json_atomic(const nlohmann::json& j, const std::string& path) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp);
    if (!out) throw std::runtime_error(path + ": cannot write");
    out << j.dump() << "\n";
    if (!out) throw std::runtime_error(tmp + ": write failed");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) throw std::runtime_error(path + ": cannot rename the temporary file into place");
}

struct InfoArgs {
  std::string checkpoint;
};

int run_info(const InfoArgs& a) {
  auto model = load_hopnet(a.checkpoint);
  const auto dict = nn::read_tensor_dict(a.checkpoint);
  std::cout << "checkpoint: " << a.checkpoint << "\n"
            << "format: " << (is_reference_checkpoint(dict) ? "reference (HOPNet authors' state dict)" : "topos") << "\n"
            << "configuration: " << model->options.to_json().dump() << "\n"
            << "parameters: " << model->num_parameters() << "\n"
            << "schedule:\n" << model->schedule().str();
  return 0;
}

struct InitArgs {
  std::string out, activation = "relu", mode = "reference";
  std::int64_t hidden = 128;
  int mlp_layers = 2, num_layers = 1;
  std::uint64_t seed = 0;
};

int run_init(const InitArgs& a) {
  torch::manual_seed(a.seed);
  Hopnet net(HopnetOptions().hidden(a.hidden).mlp_layers(a.mlp_layers).num_layers(a.num_layers).activation(nn::activation_from_string(a.activation)).mode(feature_mode_from_string(a.mode)));
  save_hopnet(*net, a.out);
  std::cout << "wrote " << a.out << " (" << net->num_parameters() << " parameters, PyTorch default initialisation, seed " << a.seed << ")\n";
  return 0;
}

struct GenerateArgs {
  std::string dataset, seeds = "1-1200", assets, out, format = "kubric";
  int jobs = 0, frames = 480;
};

// One process per job (Bullet keeps globals), each generating every jobs-th scene and
// reporting finished seeds through a pipe; scenes already on disk are skipped (resume).
int run_generate(const GenerateArgs& a) {
  namespace fs = std::filesystem;
  const auto kind = data::movi_kind_from_string(a.dataset);
  if (a.format != "kubric") throw data::DataError("unknown format '" + a.format + "' (kubric)");
  const auto seeds = data::parse_seed_range(a.seeds);
  data::MoviAssets probe(a.assets);  // fails early on a missing folder
  probe.get("dome");
  std::error_code ec;
  fs::create_directories(a.out, ec);
  {
    const auto test = fs::path(a.out) / ".write_test";
    std::ofstream t(test);
    if (ec || !t) throw data::DataError(a.out + ": output folder cannot be written");
    t.close();
    fs::remove(test);
  }
  std::vector<std::int64_t> todo;
  for (auto s : seeds)
    if (!fs::exists(fs::path(a.out) / std::to_string(s) / "metadata.json")) todo.push_back(s);
  const int jobs = std::max(1, std::min<int>(a.jobs > 0 ? a.jobs : static_cast<int>(std::thread::hardware_concurrency()), static_cast<int>(std::max<std::size_t>(todo.size(), 1))));
  std::printf("generate %s: %zu scenes (%zu already done), %d jobs, into %s\n", to_string(kind), seeds.size(), seeds.size() - todo.size(), jobs, a.out.c_str());
  std::fflush(stdout);
  int fds[2];
  if (pipe(fds) != 0) throw std::runtime_error("pipe failed");
  std::vector<pid_t> children;
  for (int j = 0; j < jobs; ++j) {
    const pid_t pid = fork();
    if (pid < 0) throw std::runtime_error("fork failed");
    if (pid == 0) {
      close(fds[0]);
      try {
        data::MoviAssets assets(a.assets);
        for (std::size_t i = static_cast<std::size_t>(j); i < todo.size(); i += static_cast<std::size_t>(jobs)) {
          const auto scene = data::generate_movi_scene(kind, static_cast<std::uint32_t>(todo[i]), assets, a.frames);
          const auto dir = fs::path(a.out) / std::to_string(todo[i]);
          fs::create_directories(dir);
          write_json_atomic(data::movi_scene_json(scene), (dir / "metadata.json").string());
          const std::int64_t done = todo[i];
          if (write(fds[1], &done, sizeof done) != sizeof done) _exit(2);
        }
      } catch (const std::exception& e) {
        std::fprintf(stderr, "\nerror: %s\n", e.what());
        _exit(1);
      }
      _exit(0);
    }
    children.push_back(pid);
  }
  close(fds[1]);
  ProgressBar bar("generate", static_cast<std::int64_t>(seeds.size()), "scenes");
  bar.resume_from(static_cast<std::int64_t>(seeds.size() - todo.size()));
  std::int64_t seed;
  while (read(fds[0], &seed, sizeof seed) == sizeof seed) bar.update(1, "seed " + std::to_string(seed));
  close(fds[0]);
  bool ok = true;
  for (pid_t c : children) {
    int status = 0;
    waitpid(c, &status, 0);
    ok = ok && WIFEXITED(status) && WEXITSTATUS(status) == 0;
  }
  bar.finish();
  if (!ok) throw std::runtime_error("a generation job failed (finished scenes are kept; run again to resume)");
  std::printf("generated %zu scenes in %.1f s (%.2f scenes/s)\n", todo.size(), bar.elapsed(), bar.rate());
  return 0;
}

struct RolloutArgs {
  std::string checkpoint, stats, scene, assets, mode = "reference", out, collisions;
  int steps = 102, threads = 1;
  bool no_collisions_json = false;
};

int run_rollout(const RolloutArgs& a) {
  const FeatureMode mode = feature_mode_from_string(a.mode);
  auto net = load_hopnet(a.checkpoint, mode);
  net->eval();
  const Normalizer norm(read_stats_json(a.stats));
  MeshLibrary lib(a.assets);
  const auto kubric = data::read_kubric_metadata(a.scene);
  const Scene scene = make_scene(kubric, lib);
  const auto geometry = make_geometry(scene, mode);
  RolloutOptions opt;
  opt.steps = a.steps;
  if (scene.num_frames < opt.steps + 4) std::cerr << "note: the scene has " << scene.num_frames << " frames; metrics cover the first " << scene.num_frames << "\n";
  // Reference mode takes the first step's contacts from collisions.json beside the scene, as the reference does.
  std::filesystem::path coll = a.collisions;
  if (coll.empty() && mode == FeatureMode::reference && !a.no_collisions_json) {
    auto dir = std::filesystem::path(kubric.source).parent_path();
    if (std::filesystem::exists(dir / "collisions.json")) coll = dir / "collisions.json";
  }
  if (!coll.empty()) {
    const auto all = read_collisions_json(coll.string());
    auto it = all.find(3);
    if (it == all.end()) throw data::DataError(coll.string() + ": has no frame 3");
    opt.first_contacts = it->second;
  }
  ProgressBar bar("rollout", opt.steps, "steps");
  opt.on_step = [&](int, int) { bar.update(); };
  const auto r = rollout(*net, norm, scene, geometry, opt);
  bar.finish();
  const auto m = rollout_metrics(r.poses, scene);
  nlohmann::json j;
  j["scene"] = kubric.source;
  j["mode"] = to_string(mode);
  j["checkpoint"] = a.checkpoint;
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
      fq.push_back({p.quaternions(i, 0), p.quaternions(i, 1), p.quaternions(i, 2), p.quaternions(i, 3)});
    }
    pos.push_back(fp);
    quat.push_back(fq);
  }
  j["positions"] = pos;
  j["quaternions"] = quat;
  write_json_atomic(j, a.out);
  std::printf("rollout: %d steps in %.3f s (%.2f ms/step), mode %s\n", opt.steps, r.seconds, 1e3 * r.seconds / opt.steps, to_string(mode));
  std::printf("%6s %10s %10s %10s %10s\n", "frame", "pos_rmse", "pos_mae", "ori_rmse", "ori_mae");
  for (int f : {4, 25, 50, 75, 100})
    if (f < static_cast<int>(m.pos_rmse.size())) std::printf("%6d %10.6f %10.6f %10.3f %10.3f\n", f, m.pos_rmse[static_cast<std::size_t>(f)], m.pos_mae[static_cast<std::size_t>(f)], m.ori_rmse[static_cast<std::size_t>(f)], m.ori_mae[static_cast<std::size_t>(f)]);
  std::printf("wrote %s\n", a.out.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"hopnet: HOPNet (Wei & Fink) on topos: inspect checkpoints and roll out scenes"};
  app.require_subcommand(1);
  int threads = 1;
  app.add_option("--threads", threads, "LibTorch intra-op threads (1 is fastest for one scene)")->capture_default_str();

  InfoArgs info;
  auto* ci = app.add_subcommand("info", "print a checkpoint's configuration, parameter count and schedule");
  ci->add_option("--checkpoint", info.checkpoint, "a topos or reference (.pt) checkpoint")->required()->check(CLI::ExistingFile);

  InitArgs in;
  auto* cn = app.add_subcommand("init", "write a freshly initialised model (a topos checkpoint)");
  cn->add_option("--out", in.out, "checkpoint to write")->required();
  cn->add_option("--hidden", in.hidden, "hidden width")->capture_default_str()->check(CLI::PositiveNumber);
  cn->add_option("--mlp-layers", in.mlp_layers, "Linear layers per MLP")->capture_default_str()->check(CLI::PositiveNumber);
  cn->add_option("--num-layers", in.num_layers, "message-passing layers")->capture_default_str()->check(CLI::PositiveNumber);
  cn->add_option("--activation", in.activation, "relu, gelu, elu or selu")->capture_default_str();
  cn->add_option("--mode", in.mode, "reference or native dual encoding")->capture_default_str();
  cn->add_option("--seed", in.seed, "initialisation seed")->capture_default_str();

  GenerateArgs ge;
  auto* cg = app.add_subcommand("generate", "regenerate MOVi scenes with Bullet, seed for seed (Kubric's metadata.json per scene)");
  cg->add_option("--dataset", ge.dataset, "movi-spheres, movi-a or movi-b")->required();
  cg->add_option("--seeds", ge.seeds, "seeds, e.g. 1-1200 or 1,5,8-10")->capture_default_str();
  cg->add_option("--assets", ge.assets, "KuBasic-layout asset folder (built-in cube/sphere/cylinder when omitted)");
  cg->add_option("--out", ge.out, "output folder (<out>/<seed>/metadata.json); existing scenes are kept")->required();
  cg->add_option("--format", ge.format, "kubric")->capture_default_str();
  cg->add_option("--jobs", ge.jobs, "processes (default: all cores)");
  cg->add_option("--frames", ge.frames, "frames per scene")->capture_default_str()->check(CLI::Range(4, 100000));

  RolloutArgs ro;
  auto* cr = app.add_subcommand("rollout", "autoregressive rollout of one scene with the paper's per-frame metrics");
  cr->add_option("--checkpoint", ro.checkpoint, "model checkpoint (topos or reference .pt)")->required()->check(CLI::ExistingFile);
  cr->add_option("--stats", ro.stats, "normalisation statistics (JSON)")->required()->check(CLI::ExistingFile);
  cr->add_option("--scene", ro.scene, "Kubric metadata.json, or the folder holding it")->required()->check(CLI::ExistingPath);
  cr->add_option("--assets", ro.assets, "meshes in the KuBasic layout (<shape>/collision_geometry.obj); built-in shapes when omitted");
  cr->add_option("--mode", ro.mode, "reference (the published model's inputs) or native")->capture_default_str();
  cr->add_option("--steps", ro.steps, "frames to predict")->capture_default_str()->check(CLI::PositiveNumber);
  cr->add_option("--collisions", ro.collisions, "collisions.json for the first step (default: beside the scene, reference mode)");
  cr->add_flag("--no-collisions-json", ro.no_collisions_json, "detect the first step's contacts too");
  cr->add_option("--out", ro.out, "output JSON")->required();

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  try {
    torch::set_num_threads(threads);
    if (*ci) return run_info(info);
    if (*cn) return run_init(in);
    if (*cg) return run_generate(ge);
    if (*cr) return run_rollout(ro);
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
  return 1;
}
