// hopnet generate: MOVi scenes regenerated with Bullet, one process per job, resumable.
#include "commands.hpp"
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <csignal>

#include <thread>

namespace hopnet_cli {
namespace {

struct GenerateArgs {
  std::string dataset, seeds = "1-1200", assets, out, format = "kubric";
  int jobs = 0, frames = 480;
};

// One process per job (Bullet keeps globals), each generating every jobs-th scene and
// reporting finished seeds through a pipe; scenes already on disk are skipped (resume).
int run_generate(const GenerateArgs& a) {
  namespace fs = std::filesystem;
  const auto kind = data::movi_kind_from_string(a.dataset);
  if (a.format != "kubric" && a.format != "topos")
    throw data::DataError("unknown format '" + a.format + "' (kubric, topos)");
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
  if (a.format == "topos" && fs::exists(fs::path(a.out) / "dataset.json")) {
    const auto have = data::Dataset::open(a.out);
    for (auto s : seeds)
      if (!have.contains(s))
        throw data::DataError(a.out + ": holds a topos dataset without seed " + std::to_string(s) +
                              "; write the new seeds elsewhere");
    fs::remove_all(fs::path(a.out) / "staging");  // a run killed after packing, before its clean-up
    std::printf("generate %s: all %zu scenes are already in %s\n", to_string(kind), seeds.size(),
                a.out.c_str());
    return 0;
  }
  // The topos format is packed at the end from Kubric scene folders in a staging folder, which
  // also makes an interrupted run resumable.
  const fs::path scenes_dir = a.format == "topos" ? fs::path(a.out) / "staging" : fs::path(a.out);
  fs::create_directories(scenes_dir);
  std::vector<std::int64_t> todo;
  for (auto s : seeds)
    if (!fs::exists(scenes_dir / std::to_string(s) / "metadata.json")) todo.push_back(s);
  const int jobs = std::max(
      1, std::min<int>(a.jobs > 0 ? a.jobs : static_cast<int>(std::thread::hardware_concurrency()),
                       static_cast<int>(std::max<std::size_t>(todo.size(), 1))));
  std::printf("generate %s: %zu scenes (%zu already done), %d jobs, into %s\n", to_string(kind),
              seeds.size(), seeds.size() - todo.size(), jobs, a.out.c_str());
  std::fflush(stdout);
  int fds[2];
  if (pipe(fds) != 0) throw std::runtime_error("pipe failed");
  std::vector<pid_t> children;
  for (int j = 0; j < jobs; ++j) {
    const pid_t pid = fork();
    if (pid < 0) throw std::runtime_error("fork failed");
    if (pid == 0) {
      // A job dies with the parent: orphans writing on would race a resumed run for the same
      // scenes.
      if (prctl(PR_SET_PDEATHSIG, SIGKILL) != 0 || getppid() == 1) _exit(1);
      close(fds[0]);
      try {
        data::MoviAssets assets(a.assets);
        for (std::size_t i = static_cast<std::size_t>(j); i < todo.size();
             i += static_cast<std::size_t>(jobs)) {
          const auto scene = data::generate_movi_scene(kind, static_cast<std::uint32_t>(todo[i]),
                                                       assets, a.frames);
          const auto dir = scenes_dir / std::to_string(todo[i]);
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
  while (read(fds[0], &seed, sizeof seed) == sizeof seed)
    bar.update(1, "seed " + std::to_string(seed));
  close(fds[0]);
  bool ok = true;
  for (pid_t c : children) {
    int status = 0;
    waitpid(c, &status, 0);
    ok = ok && WIFEXITED(status) && WEXITSTATUS(status) == 0;
  }
  bar.finish();
  if (!ok)
    throw std::runtime_error(
        "a generation job failed (finished scenes are kept; run again to resume)");
  std::printf("generated %zu scenes in %.1f s (%.2f scenes/s)\n", todo.size(), bar.elapsed(),
              bar.rate());
  if (a.format == "topos") {
    pack_scenes(scenes_dir, seeds, a.out);
    fs::remove_all(scenes_dir);
  }
  return 0;
}

}  // namespace

Command add_generate(CLI::App& app) {
  auto args = std::make_shared<GenerateArgs>();
  auto& ge = *args;
  auto* cg = app.add_subcommand("generate",
                                "regenerate MOVi scenes with Bullet, seed for seed (Kubric scene "
                                "folders or a topos dataset)");
  cg->add_option("--dataset", ge.dataset, "movi-spheres, movi-a or movi-b")->required();
  cg->add_option("--seeds", ge.seeds, "seeds, e.g. 1-1200 or 1,5,8-10")->capture_default_str();
  cg->add_option("--assets", ge.assets,
                 "KuBasic-layout asset folder (built-in cube/sphere/cylinder when omitted)");
  cg->add_option("--out", ge.out,
                 "output folder (<out>/<seed>/metadata.json); existing scenes are kept")
      ->required();
  cg->add_option("--format", ge.format,
                 "kubric (<out>/<seed>/metadata.json) or topos (dataset.json + .npy arrays, "
                 "docs/datasets.md)")
      ->capture_default_str();
  cg->add_option("--jobs", ge.jobs, "processes (default: all cores)");
  cg->add_option("--frames", ge.frames, "frames per scene")
      ->capture_default_str()
      ->check(CLI::Range(4, 100000));
  return {cg, [args] { return run_generate(*args); }};
}

}  // namespace hopnet_cli
