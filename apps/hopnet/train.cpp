// hopnet train: HOPNet on a dataset, resumable, with CSV logs. A trajectory goes through the
// network in chunks of timesteps (--chunk, or as many as fit a memory budget) whose gradients add
// up to the whole trajectory's. Data-parallel over c10d when run as several processes (torchrun's
// environment, or --nproc N here): each optimizer step takes --trajectories-per-step
// trajectories on every rank, gradients averaged by all-reduce.
#include "commands.hpp"
#include "topos/nn/device.hpp"
#include "topos/nn/distributed.hpp"
#include "launch.hpp"
#include "topos/util/malloc.hpp"
#include "topos/util/memory.hpp"
#include <chrono>
#include <cmath>
#include <ctime>
#include <future>
#include <limits>
#include <memory>
#include <mutex>
#include <numeric>
#include <random>
#include <unordered_map>
#include <unordered_set>

namespace hopnet_cli {
namespace {

// ---- train ----------------------------------------------------------------------------------
struct TrainArgs {
  std::string data, out, assets, stats, mode = "native", split_file, init, device = "auto";
  std::int64_t max_steps = -1, hidden = 0, chunk = 0;  // hidden 0: the configuration's (--config)
  double memory_budget_mb = kDefaultMemoryBudgetMb;
  double contact_cache_mb = kDefaultContactCacheMb;
  int epochs = 40, mlp_layers = 0, num_layers = 0, max_frames = 0;
  int nproc = 1, trajectories_per_step = 1, workers = 0;  // workers 0: one per core per rank
  std::string matmul_precision = "highest", cpu_gemm = "auto";
  double dist_timeout = 1800;
  VariantArgs variant;
  double lr = 1e-4, lr_decay = 0.0, min_z_collision_velocity = 0.0;
  std::int64_t checkpoint_every = 0;  // 0: the model's default (HOPNet every step, baselines 100)
  double max_seconds = 0;             // step seconds over the whole run, resumes included
  int val_rollouts = -1, val_frame = 50;  // -1: every validation scene
  std::uint64_t seed = 0;
  bool resume = false;
  bool lr_given = false;
  BaselineTrainArgs baseline;  // the options only the baselines have
};

// A scene ready for training: its meshes, geometry and, in reference mode, the reference's
// contacts when the dataset has them. Features and the batched chunks are built per optimizer
// step (a 10-object trajectory's inputs are ~100 MB; a whole dataset's would not fit).
struct LoadedScene {
  std::int64_t id;
  Scene scene;
  HopnetGeometry geometry;
  std::optional<ContactsByFrame> contacts;
};

// Each scene's detected contact candidates, kept after the trajectory's first use so that later
// epochs build its frames without the detection (about 7 % of a bfloat16 step's CPU on MOVi-A,
// docs/hopnet-training.md). The candidates depend on the ground-truth poses alone, so the frames
// are the same. Filled from the thread that builds the next trajectory, read by the validation;
// bounded by --contact-cache-mb (a scene that does not fit is detected every time).
class ContactCache {
 public:
  explicit ContactCache(double budget_mb) : budget_(budget_mb * 1024.0 * 1024.0) {}
  bool enabled() const { return budget_ > 0; }
  /// The scene's kept contacts (counted as reused), or null.
  std::shared_ptr<const ContactsByFrame> find(const LoadedScene& s) {
    const std::lock_guard<std::mutex> lock(mutex_);
    const auto it = scenes_.find(&s);
    if (it == scenes_.end()) return nullptr;
    ++reused_;
    return it->second;
  }
  /// Whether the scene's detected contacts should be offered to add(): not once they did not fit.
  bool wants(const LoadedScene& s) const {
    const std::lock_guard<std::mutex> lock(mutex_);
    return enabled() && rejected_.count(&s) == 0;
  }
  void add(const LoadedScene& s, ContactsByFrame contacts) {
    double bytes = sizeof(ContactsByFrame);
    for (const auto& [t, c] : contacts)  // a map node and a vector per frame
      bytes += 64.0 + static_cast<double>(c.capacity() * sizeof(ContactCandidate));
    const std::lock_guard<std::mutex> lock(mutex_);
    if (scenes_.count(&s) != 0) return;
    if (used_ + bytes > budget_) {
      rejected_.insert(&s);
      return;
    }
    used_ += bytes;
    scenes_.emplace(&s, std::make_shared<const ContactsByFrame>(std::move(contacts)));
  }
  /// "N scenes (reused M times), X MB" for the log.
  std::string str() const {
    const std::lock_guard<std::mutex> lock(mutex_);
    char buf[96];
    std::snprintf(buf, sizeof buf, "%zu scenes (reused %lld times), %.0f MB", scenes_.size(),
                  static_cast<long long>(reused_), used_ / 1048576.0);
    return buf;
  }

 private:
  mutable std::mutex mutex_;
  std::unordered_map<const LoadedScene*, std::shared_ptr<const ContactsByFrame>> scenes_;
  std::unordered_set<const LoadedScene*> rejected_;
  std::int64_t reused_ = 0;
  double used_ = 0, budget_;
};

std::vector<LoadedScene> load_scenes(const data::Dataset& dataset,
                                     const std::vector<std::int64_t>& ids,
                                     const std::string& assets, const SceneLiftingOptions& lifting,
                                     int max_frames, const char* label, std::FILE* log) {
  MeshLibrary lib(assets);
  std::vector<LoadedScene> out;
  out.reserve(ids.size());  // geometry points into its scene's objects: no reallocation
  ProgressBar bar(label, static_cast<std::int64_t>(ids.size()), "scenes", log);
  for (auto id : ids) {
    auto k = dataset.scene(id);
    LoadedScene ls{id, make_scene(k, lib), {}, std::nullopt};
    if (lifting.mode == FeatureMode::reference)
      if (const auto c = dataset.collisions_path(id); !c.empty())
        ls.contacts = read_collisions_json(c);
    if (max_frames > 0 && ls.scene.num_frames > max_frames) {
      ls.scene.num_frames = max_frames;
      ls.scene.positions.conservativeResize(max_frames, Eigen::NoChange);
      ls.scene.quaternions.conservativeResize(max_frames, Eigen::NoChange);
    }
    out.push_back(std::move(ls));
    auto& b = out.back();
    b.geometry = make_geometry(b.scene, lifting);
    for (auto& o : b.geometry.objects)
      o = &b.scene.objects[static_cast<std::size_t>(&o - b.geometry.objects.data())];
    bar.update();
  }
  return out;
}

int run_train(const TrainArgs& a) {
  namespace fs = std::filesystem;
  // Each model family trains with its own loop: HOPNet's below, the baselines' in baselines.cpp.
  if (!a.variant.config.empty() && config_model(a.variant.config) != "hopnet") {
    if (a.nproc > 1 || a.hidden > 0 || a.mlp_layers > 0 || a.num_layers > 0 || a.chunk > 0 ||
        !a.stats.empty() || !a.variant.activation.empty() || a.variant.collision_radius > 0 ||
        a.contact_cache_mb != kDefaultContactCacheMb)
      throw std::invalid_argument(
          "train --config " + a.variant.config +
          ": --nproc, --hidden, --mlp-layers, --num-layers, --chunk, --stats, --activation, "
          "--collision-radius and --contact-cache-mb are HOPNet's; set a baseline's fields in a "
          "JSON configuration");
    BaselineTrainArgs b = a.baseline;
    b.data = a.data, b.out = a.out, b.assets = a.assets, b.split_file = a.split_file;
    b.config = a.variant.config, b.init = a.init, b.max_steps = a.max_steps;
    b.epochs = a.epochs, b.max_frames = a.max_frames, b.seed = a.seed, b.resume = a.resume;
    b.max_seconds = a.max_seconds;
    if (a.checkpoint_every > 0) b.checkpoint_every = static_cast<int>(a.checkpoint_every);
    if (a.lr_given) b.lr = a.lr;
    return run_baseline_train(b);
  }
  if (!std::isfinite(a.contact_cache_mb) || a.contact_cache_mb < 0)
    throw std::invalid_argument(
        "train --contact-cache-mb: a number of megabytes (0: no cache), not " +
        std::to_string(a.contact_cache_mb));
  // --nproc N: this process only launches the N workers (which see RANK in their environment).
  if (a.nproc > 1 && std::getenv("RANK") == nullptr)
    return launch_local_workers(a.nproc, self_command_line());
  const auto env = nn::DistributedEnv::from_environment();
  if (a.nproc > 1 && env.world_size != a.nproc)
    throw std::invalid_argument("--nproc " + std::to_string(a.nproc) +
                                " but WORLD_SIZE=" + std::to_string(env.world_size));
  const torch::Device device = nn::device_from_string(a.device, env.local_rank);
  nn::Distributed dist(
      env, nn::DistributedOptions().device(device).timeout(
               std::chrono::milliseconds(static_cast<std::int64_t>(a.dist_timeout * 1000))));
  const bool main_rank = dist.is_main();
  const int world = dist.world_size(), per_rank = a.trajectories_per_step;
  // Workers sharing this machine share its cores (the default BLAS threads are all of them).
  if (env.local_world_size > 1 && device.is_cpu())
    nn::set_blas_threads(std::max(1, nn::available_cores() / env.local_world_size));
  // --workers: chunks at once on their own threads, each with one BLAS thread (CPU only); by
  // default this rank's share of the cores (the fastest here: 1.3 s per MOVi-A step on 2 cores
  // against 7.2 s for one chunk after another with BLAS on both, docs/training-at-scale.md).
  const int workers = !device.is_cpu() ? 1
                      : a.workers > 0  ? a.workers
                                       : std::max(1, nn::available_cores() / env.local_world_size);
  if (workers > 1) nn::set_blas_threads(1);
  nn::set_float32_matmul_precision(nn::matmul_precision_from_string(a.matmul_precision));
  // --cpu-gemm auto: oneDNN's sgemm where each worker multiplies on one thread (20-30 % faster
  // products than OpenBLAS's here, docs/hopnet-training.md), BLAS where BLAS has the cores.
  const nn::CpuGemm gemm = a.cpu_gemm != "auto" ? nn::cpu_gemm_from_string(a.cpu_gemm)
                           : device.is_cpu() && workers > 1 && nn::onednn_gemm_available()
                               ? nn::CpuGemm::onednn
                               : nn::CpuGemm::blas;
  nn::set_cpu_gemm(gemm);
  // Only rank 0 talks (and writes); the others' progress goes nowhere.
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> devnull(
      main_rank ? nullptr : std::fopen("/dev/null", "w"), &std::fclose);
  std::FILE* log = main_rank ? stderr : devnull.get();
  const auto say = [&](const char* fmt, auto... args) {
    if (!main_rank) return;
    std::printf(fmt, args...);
    std::fflush(stdout);  // a long run's log file shows each epoch as it ends
  };
  // Without AVX-512 BF16, medium's CPU products go to oneDNN's bfloat16, which emulates it:
  // slower than float32 (a MOVi-A step took 16 CPU s against 6), so the user should know.
  if (device.is_cpu() && a.matmul_precision == "medium" && !nn::detail::cpu_has_bf16())
    std::fprintf(log,
                 "hopnet train: warning: this CPU has no AVX-512 BF16, so --matmul-precision "
                 "medium runs oneDNN's emulated bfloat16 products, slower than float32 here; "
                 "--matmul-precision highest is faster\n");
  const FeatureMode mode = feature_mode_from_string(a.mode);
  HopnetOptions options = variant_options(a.variant, HopnetOptions().mode(mode));
  if (a.hidden > 0) options.hidden(a.hidden);
  if (a.mlp_layers > 0) options.mlp_layers(a.mlp_layers);
  if (a.num_layers > 0) options.num_layers(a.num_layers);
  std::map<std::string, torch::Tensor> init;
  if (!a.init.empty()) {
    init = nn::read_tensor_dict(a.init);
    options = checkpoint_options(init, a.init, options)
                  .mode(mode);  // the architecture is the checkpoint's
  }
  const double radius = options.collision_radius();
  const auto td = open_training_data(a.data, a.split_file);
  const auto& dataset = td.dataset;
  const auto& ids = dataset.ids();
  const auto &train_ids = td.train, &val_ids = td.val;
  if (main_rank) fs::create_directories(a.out);
  say("train: %zu scenes (%zu train, %zu val), %s format, mode %s, variant %s\n", ids.size(),
      train_ids.size(), val_ids.size(), dataset.format().c_str(), to_string(mode),
      variant_name(options).c_str());
  if (world > 1)
    say("distributed: %d processes (%s), %d trajectories per rank per step\n", world,
        dist.backend_name().c_str(), per_rank);
  auto train = load_scenes(dataset, train_ids, a.assets, options.lifting(), a.max_frames,
                           "scenes (train)", log);
  auto val =
      load_scenes(dataset, val_ids, a.assets, options.lifting(), a.max_frames, "scenes (val)", log);
  NormalizationStats stats;
  const auto stats_path = (fs::path(a.out) / "stats.json").string();
  // Rank 0 reads or computes the statistics and sends them to the others (the same numbers as a
  // single process, whatever the world size).
  if (main_rank) {
    if (!a.stats.empty()) {
      stats = read_stats_json(a.stats);
    } else if (a.resume && fs::exists(stats_path)) {
      stats = read_stats_json(stats_path);
    } else {
      StatsAccumulator acc;
      ProgressBar sb("statistics", static_cast<std::int64_t>(train.size()), "scenes");
      for (const auto& s : train) {
        accumulate_stats(acc,
                         trajectory_frames(s.scene, s.geometry, radius, a.min_z_collision_velocity,
                                           2, -1, s.contacts ? &*s.contacts : nullptr),
                         options.lifting().object_cells());
        sb.update();
      }
      sb.finish();
      stats = acc.finalize();
    }
    write_stats_json(stats, stats_path);
  }
  if (world > 1) {
    const auto text = dist.broadcast_bytes(
        main_rank ? data::read_text_file(stats_path) : std::string(), 0, "statistics broadcast");
    if (!main_rank) stats = parse_stats_json(text, "rank 0's statistics");
  }
  check_stats_fit(options, stats, a.stats.empty() ? stats_path : a.stats);
  const Normalizer norm(stats);

  torch::manual_seed(a.seed);
  const auto ckpt = (fs::path(a.out) / "checkpoint.pt").string(),
             opt_path = (fs::path(a.out) / "optimizer.pt").string(),
             state_path = (fs::path(a.out) / "state.json").string(),
             best_path = (fs::path(a.out) / "best.pt").string();
  // checkpoint.pt, optimizer.pt, state.json (and best.pt when it improves) are replaced together
  // (FileGroup) every --checkpoint-every steps and at every epoch's end: a run killed at any
  // point resumes from the last committed step. Only rank 0 writes, so only it recovers.
  const auto journal = (fs::path(a.out) / "commit.journal").string();
  if (a.resume && main_rank) io::recover_file_group(journal);
  Hopnet model(options);
  // Where the run stands: `epoch` epochs done, then `epoch_step` steps of the next one.
  int start_epoch = 0;
  std::int64_t step = 0, start_epoch_step = 0;
  double epoch_loss_sum = 0, epoch_seconds = 0, trained_seconds = 0;
  nlohmann::json best = nullptr;  // the validation rollouts' best epoch so far
  // Rank 0 decides whether and from what to resume; the others receive its model, optimizer
  // state and position, so --resume works for any world size (and needs no shared folder).
  const bool resuming =
      dist.broadcast_bytes(main_rank && a.resume && fs::exists(state_path) ? "1" : "0") == "1";
  if (main_rank) {
    if (resuming)
      load_checkpoint(*model, nn::read_tensor_dict(ckpt), ckpt);
    else if (!a.init.empty())
      load_checkpoint(*model, init, a.init);
  }
  model->to(device);
  dist.broadcast_(model->parameters(), 0, "parameter broadcast");
  dist.broadcast_(model->buffers(), 0, "buffer broadcast");
  const double budget = a.memory_budget_mb * 1024.0 * 1024.0;
  ContactCache contact_cache(a.contact_cache_mb);
  const auto make_chunks = [&](const LoadedScene& s) {
    const auto cached = s.contacts ? nullptr : contact_cache.find(s);  // held until built
    const ContactsByFrame* given = s.contacts ? &*s.contacts : cached.get();
    ContactsByFrame detected;
    const bool fill = given == nullptr && contact_cache.wants(s);
    const auto tf = trajectory_frames(s.scene, s.geometry, radius, a.min_z_collision_velocity, 2,
                                      -1, given, fill ? &detected : nullptr);
    if (fill) contact_cache.add(s, std::move(detected));
    auto chunks = make_training_chunks(
        s.geometry, tf, norm,
        a.chunk > 0 ? a.chunk : auto_chunk(s.geometry, tf, options.hidden(), budget / workers));
    for (auto& c : chunks) c = c.to(device);
    return chunks;
  };
  const auto timesteps = [](const std::vector<TrainingItem>& chunks) {
    std::int64_t n = 0;
    for (const auto& c : chunks) n += c.timesteps;
    return n;
  };
  torch::optim::Adam opt(model->parameters(), torch::optim::AdamOptions(a.lr));
  if (resuming) {
    const std::string opt_bytes = dist.broadcast_bytes(
        main_rank ? data::read_text_file(opt_path) : std::string(), 0, "optimizer state broadcast");
    nn::load_adam_state(
        opt, *model, nn::parse_tensor_dict(opt_bytes.data(), opt_bytes.size(), opt_path), opt_path);
    const auto st = nlohmann::json::parse(dist.broadcast_bytes(
        main_rank ? data::read_text_file(state_path) : std::string(), 0, "state broadcast"));
    start_epoch = st.at("epoch").get<int>();
    step = st.at("step").get<std::int64_t>();
    start_epoch_step = st.value("epoch_step", std::int64_t{0});
    epoch_loss_sum = st.value("epoch_loss_sum", 0.0);
    epoch_seconds = st.value("epoch_seconds", 0.0);
    trained_seconds = st.value("seconds", 0.0);
    best = st.value("best", nlohmann::json(nullptr));
    if (start_epoch_step == 0)
      say("resuming after epoch %d (step %lld)\n", start_epoch, static_cast<long long>(step));
    else
      say("resuming in epoch %d after step %lld\n", start_epoch + 1, static_cast<long long>(step));
  }
  const std::string kernels = precision_label(a.matmul_precision, device.is_cpu());
  say("model: %lld parameters, device %s, %d worker%s per trajectory, matmul precision %s, cpu "
      "gemm %s, malloc %s\n",
      static_cast<long long>(model->num_parameters()), device.str().c_str(), workers,
      workers == 1 ? "" : "s", kernels.c_str(), nn::to_string(gemm), malloc_name().c_str());
  std::ofstream steps_csv, epochs_csv;
  if (main_rank) {
    const auto steps_path = fs::path(a.out) / "steps.csv",
               epochs_path = fs::path(a.out) / "epochs.csv";
    if (a.resume) {  // the rows logged after the last commit are trained again
      truncate_csv_log(steps_path.string(), 1, step);
      truncate_csv_log(epochs_path.string(), 0, start_epoch);
    }
    const bool new_logs = !a.resume || !fs::exists(steps_path) || fs::file_size(steps_path) == 0;
    steps_csv.open(steps_path, new_logs ? std::ios::trunc : std::ios::app);
    epochs_csv.open(epochs_path, new_logs ? std::ios::trunc : std::ios::app);
    epochs_csv.precision(10);  // the validation errors that pick best.pt, as compared
    if (new_logs) {
      // seconds_per_step is wall time; cpu_seconds the process's CPU time over the step (all
      // threads), which a machine shared with other work inflates far less: the clean time.
      steps_csv << "epoch,step,scene,loss,seconds_per_step,timesteps_per_second,chunks,peak_rss_mb,"
                   "cpu_seconds\n";
      epochs_csv << "epoch,train_loss,val_loss,seconds,lr,val_rollout_pos_rmse\n";
    }
  }
  // Every optimizer step takes world × per_rank trajectories of the epoch's order (the last step
  // of an epoch may take fewer), so each trajectory is used once per epoch whatever the world size.
  const auto n_train = static_cast<std::int64_t>(train.size());
  const std::int64_t epoch_steps = nn::steps_per_epoch(n_train, world, per_rank);
  const std::int64_t all_steps = static_cast<std::int64_t>(a.epochs) * epoch_steps;
  const std::int64_t total_steps =
      a.max_steps >= 0 ? std::min<std::int64_t>(a.max_steps, all_steps) : all_steps;
  const std::int64_t checkpoint_every = a.checkpoint_every > 0 ? a.checkpoint_every : 1;
  ProgressBar bar("train", total_steps, "steps", log);
  bar.resume_from(std::min(step, total_steps));
  const auto params = model->parameters();
  // One commit of the run's state; `epochs_done` epochs complete, `epoch_step` steps into the next.
  const auto save = [&](int epochs_done, std::int64_t epoch_step, bool new_best) {
    steps_csv.flush();  // the rows of the committed steps are on disk before the commit
    epochs_csv.flush();
    io::FileGroup group(journal);
    model->to(torch::kCPU);
    save_hopnet(*model, group.stage(ckpt));
    if (new_best) save_hopnet(*model, group.stage(best_path));
    model->to(device);
    nn::write_tensor_dict(nn::adam_state_dict(opt, *model),
                          group.stage(opt_path));  // same bytes for the same state
    write_json_atomic({{"epoch", epochs_done},
                       {"step", step},
                       {"epoch_step", epoch_step},
                       {"epoch_loss_sum", epoch_loss_sum},
                       {"epoch_seconds", epoch_seconds},
                       {"seconds", trained_seconds},
                       {"best", best},
                       {"world_size", world},
                       {"trajectories_per_step", world * per_rank},
                       {"workers", workers},
                       {"matmul_precision", a.matmul_precision},
                       {"matmul_kernels", kernels}},
                      group.stage(state_path));
    group.commit();
  };
  const auto out_of_time = [&] { return a.max_seconds > 0 && trained_seconds >= a.max_seconds; };
  for (int epoch = start_epoch; epoch < a.epochs && step < total_steps && !out_of_time(); ++epoch) {
    const double lr = a.lr * (a.lr_decay > 0 ? std::pow(a.lr_decay, epoch) : 1.0);
    for (auto& g : opt.param_groups()) static_cast<torch::optim::AdamOptions&>(g.options()).lr(lr);
    const auto order = nn::epoch_order(n_train, a.seed, epoch);
    // A resumed epoch starts after its committed steps; the order is the same (seed, epoch).
    const std::int64_t first = epoch == start_epoch ? start_epoch_step : 0;
    if (first == 0) epoch_loss_sum = 0, epoch_seconds = 0;
    const std::int64_t last = std::min(epoch_steps, first + (total_steps - step));
    // This rank's trajectories of the epoch, step by step: built one ahead on another thread.
    std::vector<nn::StepShard> shards;
    std::vector<std::int64_t> mine;
    for (std::int64_t s = first; s < last; ++s) {
      shards.push_back(nn::step_shard(order, s, world, dist.rank(), per_rank));
      mine.insert(mine.end(), shards.back().items.begin(), shards.back().items.end());
    }
    model->train();
    std::future<std::vector<TrainingItem>> next;
    std::size_t taken = 0;
    if (!mine.empty())
      next = std::async(std::launch::async, make_chunks,
                        std::cref(train[static_cast<std::size_t>(mine[0])]));
    std::int64_t s = first;
    for (; s < last && !out_of_time(); ++s) {
      const auto& shard = shards[static_cast<std::size_t>(s - first)];
      reset_peak_rss();
      const auto t0 = std::chrono::steady_clock::now();
      const std::clock_t c0 = std::clock();  // the process's CPU time, every thread's
      // Gradients reset to none, as the reference's (PyTorch >= 2.0) zero_grad: a parameter no
      // trajectory of the step reaches is skipped by Adam rather than moved by its momentum.
      for (auto& p : params) p.mutable_grad() = torch::Tensor();
      double loss_sum = 0, T = 0;  // this rank's: Σ per-timestep losses, Σ timesteps
      std::size_t n_chunks = 0;
      for (std::size_t j = 0; j < shard.items.size(); ++j) {
        const std::vector<TrainingItem> chunks = next.get();
        if (++taken < mine.size())
          next = std::async(std::launch::async, make_chunks,
                            std::cref(train[static_cast<std::size_t>(mine[taken])]));
        const double loss = backward_trajectory(*model, chunks, norm, nullptr, workers);
        loss_sum += loss / static_cast<double>(timesteps(chunks));
        T += static_cast<double>(timesteps(chunks));
        n_chunks += chunks.size();
      }
      // grad = Σ over the step's trajectories / their number (one trajectory, one process: as is).
      dist.average_gradients(params, static_cast<double>(shard.total));
      opt.step();
      const auto totals = world > 1 ? dist.all_reduce_sum({loss_sum, T}, "loss all-reduce")
                                    : std::vector<double>{loss_sum, T};
      const double secs =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      const double cpu = static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
      const double l = totals[0] / static_cast<double>(shard.total);
      epoch_loss_sum += l, epoch_seconds += secs, trained_seconds += secs, ++step;
      // Every rank stops after the same step: the budget is checked on the ranks' mean time.
      if (world > 1 && a.max_seconds > 0)
        trained_seconds = dist.all_reduce_sum({trained_seconds}, "time budget")[0] / world;
      if (main_rank) {
        std::string scenes;  // every rank's trajectories of the step, from the shared order
        for (std::int64_t k = s * world * per_rank;
             k < std::min(n_train, (s + 1) * world * per_rank); ++k)
          scenes += (scenes.empty() ? "" : ";") +
                    std::to_string(
                        train[static_cast<std::size_t>(order[static_cast<std::size_t>(k)])].id);
        // chunks and peak_rss_mb are rank 0's (each process holds its own trajectories).
        steps_csv << epoch << "," << step << "," << scenes << "," << l << "," << secs << ","
                  << totals[1] / secs << "," << n_chunks << "," << peak_rss_mb() << "," << cpu
                  << "\n";
      }
      // A commit every --checkpoint-every steps and where the run stops (the step's row is
      // flushed first); the epoch's last step is committed after its validation, with the epoch.
      if (main_rank && s + 1 < epoch_steps &&
          ((s + 1) % checkpoint_every == 0 || s + 1 == last || out_of_time()))
        save(epoch, s + 1, false);
      char status[96];
      std::snprintf(status, sizeof status, "epoch %d loss %.4f %.0f timesteps/s", epoch + 1, l,
                    totals[1] / secs);
      bar.update(1, status);
    }
    if (s < epoch_steps) {  // stopped inside the epoch (--max-steps, --max-seconds): committed
      if (next.valid()) next.wait();
      break;
    }
    // Validation: rank r takes val scenes r, r + world, ...; the sums are all-reduced. The loss
    // over every timestep, and the rollout from ground-truth frames 0-3 to --val-frame, whose
    // position RMSE picks best.pt (the paper picks models by rollout, not one-step, error).
    double vl = 0, vr = std::numeric_limits<double>::quiet_NaN();
    {
      torch::NoGradGuard ng;
      model->eval();
      double v_sum = 0, r_sum = 0, r_n = 0;
      const std::size_t n_roll =
          a.val_rollouts < 0 ? val.size()
                             : std::min(val.size(), static_cast<std::size_t>(a.val_rollouts));
      for (std::size_t v = static_cast<std::size_t>(dist.rank()); v < val.size();
           v += static_cast<std::size_t>(world)) {
        const auto chunks = make_chunks(val[v]);
        double l = 0;
        for (const auto& c : chunks) l += trajectory_loss(*model, c, norm).item<double>();
        v_sum += l / static_cast<double>(timesteps(chunks));
        if (v < n_roll && val[v].scene.num_frames > a.val_frame) {
          // Rolled out at full precision whatever the training's: the model as it will be used.
          const auto precision = nn::get_float32_matmul_precision();
          nn::set_float32_matmul_precision(nn::MatmulPrecision::highest);
          RolloutOptions ro;
          ro.steps = a.val_frame - 3;
          ro.collision_radius = radius;
          const auto r = rollout(*model, norm, val[v].scene, val[v].geometry, ro);
          nn::set_float32_matmul_precision(precision);
          r_sum += rollout_metrics(r.poses, val[v].scene)
                       .pos_rmse[static_cast<std::size_t>(a.val_frame)];
          r_n += 1;
        }
      }
      if (world > 1) {
        const auto t = dist.all_reduce_sum({v_sum, r_sum, r_n}, "validation all-reduce");
        v_sum = t[0], r_sum = t[1], r_n = t[2];
      }
      if (!val.empty()) vl = v_sum / static_cast<double>(val.size());
      if (r_n > 0) vr = r_sum / r_n;
    }
    if (!main_rank) continue;
    const bool new_best =
        std::isfinite(vr) && (best.is_null() || vr < best.at("val_rollout_pos_rmse").get<double>());
    if (new_best)
      best = {{"epoch", epoch + 1},
              {"step", step},
              {"frame", a.val_frame},
              {"val_rollout_pos_rmse", vr}};
    epochs_csv << epoch + 1 << "," << epoch_loss_sum / static_cast<double>(epoch_steps) << "," << vl
               << "," << epoch_seconds << "," << lr << "," << vr << "\n";
    if (contact_cache.enabled())
      say("epoch %d: contacts kept for %s\n", epoch + 1, contact_cache.str().c_str());
    if (std::isfinite(vr))
      say("epoch %d: validation rollout position RMSE at frame %d %.5f m%s\n", epoch + 1,
          a.val_frame, vr, new_best ? " (best so far: best.pt)" : "");
    save(epoch + 1, 0, new_best);
  }
  bar.finish();
  // Nobody leaves before rank 0 has written the last checkpoint (a launcher may stop the rest).
  dist.barrier("final barrier");
  say("trained %lld steps; checkpoint %s, statistics %s\n", static_cast<long long>(step),
      ckpt.c_str(), stats_path.c_str());
  return 0;
}

}  // namespace

Command add_train(CLI::App& app) {
  auto args = std::make_shared<TrainArgs>();
  auto& tr = *args;
  auto* ct = app.add_subcommand("train",
                                "train HOPNet on a dataset, topos format or Kubric scene folders "
                                "(one optimizer step per trajectory)");
  ct->add_option("--data", tr.data, "dataset folder: topos format or Kubric scene folders")
      ->required()
      ->check(CLI::ExistingDirectory);
  ct->add_option("--split-file", tr.split_file,
                 "custom split JSON {train, val, test} (default: the reference split)")
      ->check(CLI::ExistingFile);
  ct->add_option("--out", tr.out,
                 "output folder: checkpoint.pt, stats.json, steps.csv (with peak_rss_mb per step), "
                 "epochs.csv")
      ->required();
  ct->add_option("--assets", tr.assets,
                 "KuBasic-layout asset folder (built-in shapes when omitted)");
  ct->add_option("--stats", tr.stats,
                 "normalisation statistics (default: computed from the training split)");
  ct->add_option("--init", tr.init,
                 "start from these weights (topos or reference checkpoint; its architecture wins "
                 "over --hidden etc.)")
      ->check(CLI::ExistingFile);
  ct->add_option("--chunk", tr.chunk,
                 "timesteps per forward/backward (0: as many as fit --memory-budget-mb)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  ct->add_option("--memory-budget-mb", tr.memory_budget_mb,
                 "activation memory for the chunks in flight (one per worker)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  ct->add_option("--contact-cache-mb", tr.contact_cache_mb,
                 "memory (per process) for the training and validation scenes' detected "
                 "contacts, kept from one epoch to the next (the same frames, without the "
                 "detection; 0: detect every time)")
      ->capture_default_str();
  ct->add_option("--workers", tr.workers,
                 "chunks of a trajectory run at once, each on its own thread with one BLAS "
                 "thread (CPU; 0: one per core of this rank's share; 1: one after the other, "
                 "BLAS on every core)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  ct->add_option("--matmul-precision", tr.matmul_precision,
                 "float32 products: highest (float32, the reference's numbers) or medium "
                 "(bfloat16 inputs, float32 accumulation: ~3x faster products on CPUs with "
                 "AVX-512 BF16 and on GPUs)")
      ->capture_default_str()
      ->check(CLI::IsMember({"highest", "medium"}));
  ct->add_option("--cpu-gemm", tr.cpu_gemm,
                 "library of the float32 products on the CPU: onednn (oneDNN's sgemm, one "
                 "thread per worker), topos (topos's dense kernel, one thread), blas (OpenBLAS "
                 "through LibTorch), or auto (onednn with several workers, else blas); they "
                 "differ in summation order only")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "blas", "onednn", "topos"}));
  ct->add_option("--max-steps", tr.max_steps, "stop after this many optimizer steps");
  ct->add_option("--epochs", tr.epochs, "epochs")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  auto* lr =
      ct->add_option("--lr", tr.lr, "Adam learning rate (baselines: 1e-3)")->capture_default_str();
  ct->add_option("--lr-decay", tr.lr_decay,
                 "exponential decay per epoch (0: constant; the paper's 0.9441)")
      ->capture_default_str();
  add_variant_options(ct, tr.variant, true);
  ct->add_option("--hidden", tr.hidden, "hidden width (default: the configuration's)")
      ->check(CLI::PositiveNumber);
  ct->add_option("--mlp-layers", tr.mlp_layers,
                 "Linear layers per MLP (default: the configuration's)")
      ->check(CLI::PositiveNumber);
  ct->add_option("--num-layers", tr.num_layers,
                 "message-passing layers (default: the configuration's)")
      ->check(CLI::PositiveNumber);
  ct->add_option("--mode", tr.mode, "native or reference features")->capture_default_str();
  ct->add_option("--max-frames", tr.max_frames, "use only the first frames of each scene (0: all)")
      ->capture_default_str();
  ct->add_option("--min-z-collision-velocity", tr.min_z_collision_velocity,
                 "mask objects in contact slower than this vertically (m/s)")
      ->capture_default_str();
  ct->add_option("--seed", tr.seed, "random seed")->capture_default_str();
  ct->add_flag("--resume", tr.resume,
               "continue from the last epoch's checkpoint in --out (any number of processes)");
  ct->add_option("--device", tr.device,
                 "cpu, cuda, cuda:N or auto (a worker's GPU is its LOCAL_RANK)")
      ->capture_default_str();
  ct->add_option("--nproc", tr.nproc,
                 "start this many local data-parallel workers (Gloo over loopback); torchrun's "
                 "environment does the same across machines")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  ct->add_option("--trajectories-per-step", tr.trajectories_per_step,
                 "trajectories per optimizer step on each process (gradients averaged)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  ct->add_option("--dist-timeout", tr.dist_timeout,
                 "seconds a process waits for the others in a collective before failing")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  ct->add_option("--batch-timesteps", tr.baseline.batch_timesteps,
                 "baselines: random (scene, t) timesteps per optimizer step")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  ct->add_option("--lr-schedule", tr.baseline.lr_schedule,
                 "baselines: constant, or reference-fignet (lr · 0.1^(step/1e6) + 1e-6)")
      ->capture_default_str()
      ->check(CLI::IsMember({"constant", "reference-fignet"}));
  ct->add_option("--checkpoint-every", tr.checkpoint_every,
                 "steps between checkpoints (HOPNet: default 1, every step, so a kill loses at "
                 "most the step in flight; baselines: validation and checkpoint, default 100)")
      ->check(CLI::PositiveNumber);
  ct->add_option("--val-rollouts", tr.val_rollouts,
                 "HOPNet: validation scenes rolled out at each epoch's end to pick best.pt "
                 "(-1: all, 0: none)")
      ->capture_default_str()
      ->check(CLI::Range(-1, 1 << 30));
  ct->add_option("--val-frame", tr.val_frame,
                 "HOPNet: the frame whose position RMSE over the validation rollouts picks best.pt")
      ->capture_default_str()
      ->check(CLI::Range(4, 1 << 20));
  ct->add_option("--stats-stride", tr.baseline.stats_stride,
                 "baselines: statistics from every n-th training timestep")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  ct->add_option("--max-seconds", tr.max_seconds,
                 "stop once the optimizer steps have taken this long over the whole run, resumes "
                 "included (a wall-time budget; the checkpoint is written)")
      ->check(CLI::NonNegativeNumber);
  ct->add_option("--val-timesteps", tr.baseline.val_timesteps,
                 "baselines: validation timesteps (a fixed random sample)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  ct->set_config("--config-file", "", "read options from a TOML/INI file");
  return {ct, [args, lr] {
            args->lr_given = lr->count() > 0;
            return run_train(*args);
          }};
}

}  // namespace hopnet_cli
