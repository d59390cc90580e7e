// hopnet train: HOPNet on a dataset (one optimizer step per trajectory), resumable, with CSV logs.
// A trajectory goes through the network in chunks of timesteps (--chunk, or as many as fit a
// memory budget) whose gradients add up to the whole trajectory's.
#include "commands.hpp"
#include "topos/util/memory.hpp"
#include <chrono>
#include <future>
#include <numeric>
#include <random>

namespace hopnet_cli {
namespace {

// ---- train ----------------------------------------------------------------------------------
struct TrainArgs {
  std::string data, out, assets, stats, mode = "native", split_file, init;
  std::int64_t max_steps = -1, hidden = 0, chunk = 0;  // hidden 0: the configuration's (--config)
  double memory_budget_mb = kDefaultMemoryBudgetMb;
  int epochs = 40, mlp_layers = 0, num_layers = 0, max_frames = 0;
  VariantArgs variant;
  double lr = 1e-4, lr_decay = 0.0, min_z_collision_velocity = 0.0;
  std::uint64_t seed = 0;
  bool resume = false;
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

std::vector<LoadedScene> load_scenes(const data::Dataset& dataset, const std::vector<std::int64_t>& ids, const std::string& assets, const LiftingOptions& lifting, int max_frames, const char* label) {
  MeshLibrary lib(assets);
  std::vector<LoadedScene> out;
  out.reserve(ids.size());  // geometry points into its scene's objects: no reallocation
  ProgressBar bar(label, static_cast<std::int64_t>(ids.size()), "scenes");
  for (auto id : ids) {
    auto k = dataset.scene(id);
    LoadedScene ls{id, make_scene(k, lib), {}, std::nullopt};
    if (lifting.mode == FeatureMode::reference)
      if (const auto c = dataset.collisions_path(id); !c.empty()) ls.contacts = read_collisions_json(c);
    if (max_frames > 0 && ls.scene.num_frames > max_frames) {
      ls.scene.num_frames = max_frames;
      ls.scene.positions.conservativeResize(max_frames, Eigen::NoChange);
      ls.scene.quaternions.conservativeResize(max_frames, Eigen::NoChange);
    }
    out.push_back(std::move(ls));
    auto& b = out.back();
    b.geometry = make_geometry(b.scene, lifting);
    for (auto& o : b.geometry.objects) o = &b.scene.objects[static_cast<std::size_t>(&o - b.geometry.objects.data())];
    bar.update();
  }
  return out;
}

int run_train(const TrainArgs& a) {
  namespace fs = std::filesystem;
  const FeatureMode mode = feature_mode_from_string(a.mode);
  HopnetOptions options = variant_options(a.variant, HopnetOptions().mode(mode));
  if (a.hidden > 0) options.hidden(a.hidden);
  if (a.mlp_layers > 0) options.mlp_layers(a.mlp_layers);
  if (a.num_layers > 0) options.num_layers(a.num_layers);
  std::map<std::string, torch::Tensor> init;
  if (!a.init.empty()) {
    init = nn::read_tensor_dict(a.init);
    options = checkpoint_options(init, a.init, options).mode(mode);  // the architecture is the checkpoint's
  }
  const double radius = options.collision_radius();
  const auto dataset = data::Dataset::open(a.data);
  const auto& ids = dataset.ids();
  const auto split = a.split_file.empty() ? data::reference_split(ids) : data::read_split_json(a.split_file);
  const auto train_ids = data::split_part(split, "train", ids), val_ids = data::split_part(split, "val", ids);
  if (train_ids.empty()) throw data::DataError(a.data + ": no training scenes");
  fs::create_directories(a.out);
  std::printf("train: %zu scenes (%zu train, %zu val), %s format, mode %s, variant %s\n", ids.size(), train_ids.size(), val_ids.size(), dataset.format().c_str(), to_string(mode), variant_name(options).c_str());
  auto train = load_scenes(dataset, train_ids, a.assets, options.lifting(), a.max_frames, "scenes (train)");
  auto val = load_scenes(dataset, val_ids, a.assets, options.lifting(), a.max_frames, "scenes (val)");
  NormalizationStats stats;
  const auto stats_path = (fs::path(a.out) / "stats.json").string();
  if (!a.stats.empty()) {
    stats = read_stats_json(a.stats);
  } else if (a.resume && fs::exists(stats_path)) {
    stats = read_stats_json(stats_path);
  } else {
    StatsAccumulator acc;
    ProgressBar sb("statistics", static_cast<std::int64_t>(train.size()), "scenes");
    for (const auto& s : train) {
      accumulate_stats(acc, trajectory_frames(s.scene, s.geometry, radius, a.min_z_collision_velocity, 2, -1, s.contacts ? &*s.contacts : nullptr), options.lifting().object_cells());
      sb.update();
    }
    sb.finish();
    stats = acc.finalize();
  }
  check_stats_fit(options, stats, a.stats.empty() ? stats_path : a.stats);
  write_stats_json(stats, stats_path);
  const Normalizer norm(stats);
  const torch::Device device = torch::cuda::is_available() ? torch::kCUDA : torch::kCPU;

  torch::manual_seed(a.seed);
  const auto ckpt = (fs::path(a.out) / "checkpoint.pt").string(), opt_path = (fs::path(a.out) / "optimizer.pt").string(), state_path = (fs::path(a.out) / "state.json").string();
  Hopnet model(options);
  int start_epoch = 0;
  std::int64_t step = 0;
  const bool resuming = a.resume && fs::exists(state_path);
  if (resuming) load_checkpoint(*model, nn::read_tensor_dict(ckpt), ckpt);
  else if (!a.init.empty()) load_checkpoint(*model, init, a.init);
  model->to(device);
  const double budget = a.memory_budget_mb * 1024.0 * 1024.0;
  const auto make_chunks = [&](const LoadedScene& s) {
    const auto tf = trajectory_frames(s.scene, s.geometry, radius, a.min_z_collision_velocity, 2, -1, s.contacts ? &*s.contacts : nullptr);
    auto chunks = make_training_chunks(s.geometry, tf, norm, a.chunk > 0 ? a.chunk : auto_chunk(s.geometry, tf, options.hidden(), budget));
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
    torch::load(opt, opt_path);
    std::ifstream in(state_path);
    const auto st = nlohmann::json::parse(in);
    start_epoch = st.at("epoch").get<int>();
    step = st.at("step").get<std::int64_t>();
    std::printf("resuming after epoch %d (step %lld)\n", start_epoch, static_cast<long long>(step));
  }
  std::printf("model: %lld parameters, device %s\n", static_cast<long long>(model->num_parameters()), device.str().c_str());
  std::ofstream steps_csv(fs::path(a.out) / "steps.csv", a.resume ? std::ios::app : std::ios::trunc);
  std::ofstream epochs_csv(fs::path(a.out) / "epochs.csv", a.resume ? std::ios::app : std::ios::trunc);
  if (!a.resume || step == 0) {
    steps_csv << "epoch,step,scene,loss,seconds_per_step,timesteps_per_second,chunks,peak_rss_mb\n";
    epochs_csv << "epoch,train_loss,val_loss,seconds,lr\n";
  }
  const std::int64_t total_steps = a.max_steps >= 0 ? std::min<std::int64_t>(a.max_steps, static_cast<std::int64_t>(a.epochs) * static_cast<std::int64_t>(train.size()))
                                                    : static_cast<std::int64_t>(a.epochs) * static_cast<std::int64_t>(train.size());
  ProgressBar bar("train", total_steps, "steps");
  bar.resume_from(std::min(step, total_steps));
  for (int epoch = start_epoch; epoch < a.epochs && step < total_steps; ++epoch) {
    const double lr = a.lr * (a.lr_decay > 0 ? std::pow(a.lr_decay, epoch) : 1.0);
    for (auto& g : opt.param_groups()) static_cast<torch::optim::AdamOptions&>(g.options()).lr(lr);
    std::vector<std::size_t> order(train.size());
    std::iota(order.begin(), order.end(), 0);
    std::shuffle(order.begin(), order.end(), std::mt19937(static_cast<std::uint32_t>(a.seed * 1000 + static_cast<std::uint64_t>(epoch))));
    const auto t_epoch = std::chrono::steady_clock::now();
    double sum = 0;
    int n = 0;
    model->train();
    // The next trajectory's item is built on another thread while this one trains.
    std::future<std::vector<TrainingItem>> next;
    const auto steps_left = [&](std::size_t k) { return step + static_cast<std::int64_t>(k) < total_steps; };
    if (!order.empty() && steps_left(0)) next = std::async(std::launch::async, make_chunks, std::cref(train[order[0]]));
    for (std::size_t k = 0; k < order.size() && step < total_steps; ++k) {
      const auto i = order[k];
      const std::vector<TrainingItem> chunks = next.get();
      if (k + 1 < order.size() && steps_left(1)) next = std::async(std::launch::async, make_chunks, std::cref(train[order[k + 1]]));
      reset_peak_rss();
      const auto t0 = std::chrono::steady_clock::now();
      const double loss = train_step(*model, opt, chunks, norm);
      const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      const auto T = timesteps(chunks);
      const double l = loss / static_cast<double>(T);
      sum += l, ++n, ++step;
      steps_csv << epoch << "," << step << "," << train[i].id << "," << l << "," << secs << "," << static_cast<double>(T) / secs << "," << chunks.size() << "," << peak_rss_mb() << "\n";
      char status[96];
      std::snprintf(status, sizeof status, "epoch %d loss %.4f %.0f timesteps/s", epoch + 1, l, static_cast<double>(T) / secs);
      bar.update(1, status);
    }
    steps_csv.flush();
    double vl = 0;
    {
      torch::NoGradGuard ng;
      model->eval();
      for (const auto& v : val) {
        const auto chunks = make_chunks(v);
        double l = 0;
        for (const auto& c : chunks) l += trajectory_loss(*model, c, norm).item<double>();
        vl += l / static_cast<double>(timesteps(chunks));
      }
      if (!val.empty()) vl /= static_cast<double>(val.size());
    }
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_epoch).count();
    epochs_csv << epoch + 1 << "," << (n ? sum / n : 0.0) << "," << vl << "," << secs << "," << lr << "\n";
    epochs_csv.flush();
    model->to(torch::kCPU);
    save_hopnet(*model, ckpt);
    model->to(device);
    std::ostringstream optimizer_state;
    torch::save(opt, optimizer_state);
    write_file_atomic(opt_path, optimizer_state.str());
    write_json_atomic({{"epoch", epoch + 1}, {"step", step}}, state_path);
  }
  bar.finish();
  std::printf("trained %lld steps; checkpoint %s, statistics %s\n", static_cast<long long>(step), ckpt.c_str(), stats_path.c_str());
  return 0;
}

}  // namespace

Command add_train(CLI::App& app) {
  auto args = std::make_shared<TrainArgs>();
  auto& tr = *args;
  auto* ct = app.add_subcommand("train", "train HOPNet on a dataset, topos format or Kubric scene folders (one optimizer step per trajectory)");
  ct->add_option("--data", tr.data, "dataset folder: topos format or Kubric scene folders")->required()->check(CLI::ExistingDirectory);
  ct->add_option("--split-file", tr.split_file, "custom split JSON {train, val, test} (default: the reference split)")->check(CLI::ExistingFile);
  ct->add_option("--out", tr.out, "output folder: checkpoint.pt, stats.json, steps.csv (with peak_rss_mb per step), epochs.csv")->required();
  ct->add_option("--assets", tr.assets, "KuBasic-layout asset folder (built-in shapes when omitted)");
  ct->add_option("--stats", tr.stats, "normalisation statistics (default: computed from the training split)");
  ct->add_option("--init", tr.init, "start from these weights (topos or reference checkpoint; its architecture wins over --hidden etc.)")->check(CLI::ExistingFile);
  ct->add_option("--chunk", tr.chunk, "timesteps per forward/backward (0: as many as fit --memory-budget-mb)")->capture_default_str()->check(CLI::NonNegativeNumber);
  ct->add_option("--memory-budget-mb", tr.memory_budget_mb, "activation memory for one chunk")->capture_default_str()->check(CLI::PositiveNumber);
  ct->add_option("--max-steps", tr.max_steps, "stop after this many optimizer steps");
  ct->add_option("--epochs", tr.epochs, "epochs")->capture_default_str()->check(CLI::PositiveNumber);
  ct->add_option("--lr", tr.lr, "Adam learning rate")->capture_default_str();
  ct->add_option("--lr-decay", tr.lr_decay, "exponential decay per epoch (0: constant; the paper's 0.9441)")->capture_default_str();
  add_variant_options(ct, tr.variant, true);
  ct->add_option("--hidden", tr.hidden, "hidden width (default: the configuration's)")->check(CLI::PositiveNumber);
  ct->add_option("--mlp-layers", tr.mlp_layers, "Linear layers per MLP (default: the configuration's)")->check(CLI::PositiveNumber);
  ct->add_option("--num-layers", tr.num_layers, "message-passing layers (default: the configuration's)")->check(CLI::PositiveNumber);
  ct->add_option("--mode", tr.mode, "native or reference features")->capture_default_str();
  ct->add_option("--max-frames", tr.max_frames, "use only the first frames of each scene (0: all)")->capture_default_str();
  ct->add_option("--min-z-collision-velocity", tr.min_z_collision_velocity, "mask objects in contact slower than this vertically (m/s)")->capture_default_str();
  ct->add_option("--seed", tr.seed, "random seed")->capture_default_str();
  ct->add_flag("--resume", tr.resume, "continue from the last epoch's checkpoint in --out");
  ct->set_config("--config-file", "", "read options from a TOML/INI file");
  return {ct, [args] { return run_train(*args); }};
}

}  // namespace hopnet_cli
