// The paper's baselines' training in the hopnet program (`train --config fignet|mgn|...`; info,
// rollout and evaluate run them as any model, through sim::open_model). Training follows the
// FIGNet reimplementation: batches of random (scene, t) timesteps of the training split, Adam,
// the loss on the dynamic nodes' normalised accelerations; statistics come from the training
// split only and are saved inside the checkpoint.
#include "commands.hpp"
#include "topos/models/baselines.hpp"
#include "topos/nn/distributed.hpp"
#include "topos/util/memory.hpp"

#include <chrono>
#include <future>
#include <random>

namespace hopnet_cli {

int run_baseline_train(const BaselineTrainArgs& a) {
  namespace fs = std::filesystem;
  const auto config = models::baselines::parse_baseline_config(a.config);
  const auto spec = config.spec();
  const auto td = open_training_data(a.data, a.split_file);
  const auto& dataset = td.dataset;
  const auto& ids = dataset.ids();
  const auto &train_ids = td.train, &val_ids = td.val;
  if (a.batch_timesteps < 1) throw std::invalid_argument("--batch-timesteps must be positive");
  fs::create_directories(a.out);
  const auto ckpt = (fs::path(a.out) / "checkpoint.pt").string(),
             opt_path = (fs::path(a.out) / "optimizer.pt").string(),
             state_path = (fs::path(a.out) / "state.json").string(),
             journal = (fs::path(a.out) / "commit.journal").string();
  if (a.resume) io::recover_file_group(journal);
  const bool resuming = a.resume && fs::exists(state_path);
  std::map<std::string, torch::Tensor> resumed;  // the checkpoint resumed from, read once
  if (resuming) {  // the model before anything else: its statistics would not fit another's
    resumed = nn::read_tensor_dict(ckpt);
    const auto cfg = models::baselines::checkpoint_config(resumed, ckpt);
    const std::string model = cfg.value("model", "hopnet");
    if (model != config.model())
      throw std::invalid_argument(ckpt + ": a " + model + " checkpoint (topos.config model '" +
                                  model + "'); --config asks for " + config.model());
    // Compared as read (a checkpoint written with an older key reads the same).
    if (models::baselines::BaselineConfig::from_json(cfg).to_json() != config.to_json())
      throw std::invalid_argument(ckpt + ": trained as " + cfg.dump() + ", --config asks for " +
                                  config.to_json().dump());
  }
  std::printf("train: %s (%s), %zu scenes (%zu train, %zu val), %s format\n", config.name().c_str(),
              config.to_json().dump().c_str(), ids.size(), train_ids.size(), val_ids.size(),
              dataset.format().c_str());

  struct Loaded {
    std::int64_t id;
    Scene scene;
    std::unique_ptr<models::baselines::SceneGraphs> graphs;
  };
  MeshLibrary lib(a.assets);
  const auto load = [&](const std::vector<std::int64_t>& which, const char* label) {
    std::vector<Loaded> out;
    ProgressBar bar(label, static_cast<std::int64_t>(which.size()), "scenes");
    for (auto id : which) {
      Loaded l{id, make_scene(dataset.scene(id), lib), nullptr};
      if (a.max_frames > 0 && l.scene.num_frames > a.max_frames) {
        l.scene.num_frames = a.max_frames;
        l.scene.positions.conservativeResize(a.max_frames, Eigen::NoChange);
        l.scene.quaternions.conservativeResize(a.max_frames, Eigen::NoChange);
      }
      if (l.scene.num_frames < 4)
        throw data::DataError(a.data + ": scene " + std::to_string(id) +
                              " has fewer than 4 frames");
      l.graphs = std::make_unique<models::baselines::SceneGraphs>(config, l.scene);
      out.push_back(std::move(l));
      bar.update();
    }
    return out;
  };
  const auto train = load(train_ids, "scenes (train)");
  const auto val = load(val_ids, "scenes (val)");
  // Every step with a target: inputs t-2..t, target t+1, t = 2 .. frames-2.
  std::vector<std::pair<std::size_t, std::int64_t>> samples;
  for (std::size_t s = 0; s < train.size(); ++s)
    for (std::int64_t t = 2; t + 1 < train[s].scene.num_frames; ++t) samples.emplace_back(s, t);
  const auto frame_of = [&](const std::vector<Loaded>& set,
                            std::pair<std::size_t, std::int64_t> st) {
    return set[st.first].graphs->frame(set[st.first].scene, st.second);
  };

  const auto stats_path = (fs::path(a.out) / "stats.json").string();
  models::gns::Statistics stats;
  if (a.resume && fs::exists(stats_path)) {
    stats = models::gns::Statistics::load(stats_path);
  } else {
    // Every stats_stride-th timestep of the training split (the reimplementation's warm-up sees
    // 2,000 random batches of 64).
    models::gns::StatisticsAccumulator acc(spec);
    std::vector<std::pair<std::size_t, std::int64_t>> chosen;
    for (std::size_t i = 0; i < samples.size(); i += static_cast<std::size_t>(a.stats_stride))
      chosen.push_back(samples[i]);
    ProgressBar bar("statistics", static_cast<std::int64_t>(chosen.size()), "timesteps");
    for (const auto& st : chosen) {
      acc.add(frame_of(train, st));
      bar.update();
    }
    bar.finish();
    stats = acc.finish();
    stats.save(stats_path);
  }
  stats.check_fits(spec, stats_path);

  torch::manual_seed(a.seed);
  models::baselines::Baseline model(config);
  torch::optim::Adam opt(model.net->parameters(), torch::optim::AdamOptions(a.lr));
  std::int64_t step = 0;
  // Weights from a baseline checkpoint of this model (load_baseline checks it whole).
  const auto adopt = [&](const std::map<std::string, torch::Tensor>& dict,
                         const std::string& path) {
    const auto loaded = models::baselines::load_baseline(dict, path, config.model());
    torch::NoGradGuard ng;
    auto src = loaded.model.net->named_parameters();
    for (auto& p : model.net->named_parameters()) p.value().copy_(src[p.key()]);
  };
  if (resuming) {
    adopt(resumed, ckpt);
    nn::load_adam_state(opt, *model.net, nn::read_tensor_dict(opt_path), opt_path);
    step = data::read_json_file(state_path).at("step").get<std::int64_t>();
    std::printf("resuming after step %lld\n", static_cast<long long>(step));
  } else if (!a.init.empty()) {
    adopt(nn::read_tensor_dict(a.init), a.init);
  }
  std::printf("model: %s, %lld parameters, %d timesteps per step, lr %g (%s)\n",
              config.name().c_str(), static_cast<long long>(model.num_parameters()),
              a.batch_timesteps, a.lr, a.lr_schedule.c_str());

  const auto n_samples = static_cast<std::int64_t>(samples.size());
  const std::int64_t epoch_steps = (n_samples + a.batch_timesteps - 1) / a.batch_timesteps;
  const std::int64_t total_steps = a.max_steps >= 0
                                       ? std::min<std::int64_t>(a.max_steps, a.epochs * epoch_steps)
                                       : a.epochs * epoch_steps;
  const auto lr_at = [&](std::int64_t s) {
    // The reimplementation's schedule: 1e-3 · 0.1^(s / 1e6) + 1e-6, scaled to --lr.
    return a.lr_schedule == "reference-fignet" ? a.lr * std::pow(0.1, s / 1e6) + 1e-6 : a.lr;
  };
  // Validation: a fixed sample of validation timesteps, at every checkpoint.
  std::vector<std::pair<std::size_t, std::int64_t>> val_samples;
  {
    std::mt19937_64 rng(a.seed + 1);
    std::vector<std::pair<std::size_t, std::int64_t>> all;
    for (std::size_t s = 0; s < val.size(); ++s)
      for (std::int64_t t = 2; t + 1 < val[s].scene.num_frames; ++t) all.emplace_back(s, t);
    std::shuffle(all.begin(), all.end(), rng);
    all.resize(std::min<std::size_t>(all.size(), static_cast<std::size_t>(a.val_timesteps)));
    val_samples = std::move(all);
  }
  std::ofstream steps_csv, checks_csv;
  {
    const auto steps_path = fs::path(a.out) / "steps.csv",
               checks_path = fs::path(a.out) / "checks.csv";
    if (resuming) {
      truncate_csv_log(steps_path.string(), 0, step);
      truncate_csv_log(checks_path.string(), 0, step);
    }
    const bool fresh = !resuming || !fs::exists(steps_path);
    steps_csv.open(steps_path, fresh ? std::ios::trunc : std::ios::app);
    checks_csv.open(checks_path, fresh ? std::ios::trunc : std::ios::app);
    if (fresh) {
      steps_csv << "step,loss,seconds_per_step,timesteps_per_second,lr,peak_rss_mb\n";
      checks_csv << "step,train_loss,val_loss,seconds\n";
    }
  }
  // The batch of step s: the epoch's shuffled sample order, so a resumed run sees the same data.
  // One batch is built at a time (on the prefetch thread), so the epoch's order is cached here.
  std::pair<std::int64_t, std::vector<std::int64_t>> cached{-1, {}};
  const auto batch_of = [&](std::int64_t s) {
    const std::int64_t epoch = s / epoch_steps, k = s % epoch_steps;
    if (cached.first != epoch) cached = {epoch, nn::epoch_order(n_samples, a.seed, epoch)};
    const auto& order = cached.second;
    std::vector<models::gns::GraphFrame> frames;
    for (std::int64_t i = k * a.batch_timesteps;
         i < std::min(n_samples, (k + 1) * a.batch_timesteps); ++i)
      frames.push_back(
          frame_of(train, samples[static_cast<std::size_t>(order[static_cast<std::size_t>(i)])]));
    std::vector<const models::gns::GraphFrame*> ptr;
    for (const auto& f : frames) ptr.push_back(&f);
    return models::gns::collate(spec, ptr, stats);
  };
  const auto validate = [&] {
    torch::NoGradGuard ng;
    model.net->eval();
    double sum = 0;
    std::size_t n = 0;
    for (std::size_t i = 0; i < val_samples.size(); i += 16) {
      std::vector<models::gns::GraphFrame> frames;
      for (std::size_t j = i; j < std::min(val_samples.size(), i + 16); ++j)
        frames.push_back(frame_of(val, val_samples[j]));
      std::vector<const models::gns::GraphFrame*> ptr;
      for (const auto& f : frames) ptr.push_back(&f);
      const auto b = models::gns::collate(spec, ptr, stats);
      sum += models::gns::acceleration_loss(model.net->forward(b).at("mesh"), b).item<double>() *
             static_cast<double>(frames.size());
      n += frames.size();
    }
    model.net->train();
    return n ? sum / static_cast<double>(n) : 0.0;
  };
  double trained_seconds = resuming ? data::read_json_file(state_path).value("seconds", 0.0) : 0;
  const auto save = [&] {
    io::FileGroup group(journal);
    models::baselines::save_baseline(model, stats, group.stage(ckpt));
    nn::write_tensor_dict(nn::adam_state_dict(opt, *model.net), group.stage(opt_path));
    write_json_atomic({{"step", step}, {"seconds", trained_seconds}, {"model", config.to_json()}},
                      group.stage(state_path));
    group.commit();
  };

  ProgressBar bar("train", total_steps, "steps");
  bar.resume_from(std::min(step, total_steps));
  model.net->train();
  const auto t_start = std::chrono::steady_clock::now();
  double loss_sum = 0;
  std::int64_t loss_n = 0;
  std::future<models::gns::GraphBatch> next;
  if (step < total_steps) next = std::async(std::launch::async, batch_of, step);
  bool out_of_time = a.max_seconds > 0 && trained_seconds >= a.max_seconds;  // spent before
  while (step < total_steps && !out_of_time) {
    reset_peak_rss();
    const auto t0 = std::chrono::steady_clock::now();
    const models::gns::GraphBatch batch = next.get();  // built while the previous step ran
    if (step + 1 < total_steps) next = std::async(std::launch::async, batch_of, step + 1);
    const double lr = lr_at(step);
    for (auto& g : opt.param_groups()) static_cast<torch::optim::AdamOptions&>(g.options()).lr(lr);
    opt.zero_grad();
    const auto loss = models::gns::acceleration_loss(model.net->forward(batch).at("mesh"), batch);
    loss.backward();
    opt.step();
    ++step;
    const double l = loss.item<double>(),
                 secs =
                     std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    loss_sum += l, ++loss_n;
    trained_seconds += secs;
    out_of_time = a.max_seconds > 0 && trained_seconds >= a.max_seconds;
    const auto frames = static_cast<double>(batch.node_offset.size() - 1);
    steps_csv << step << "," << l << "," << secs << "," << frames / secs << "," << lr << ","
              << peak_rss_mb() << "\n";
    char status[96];
    std::snprintf(status, sizeof status, "loss %.4f %.1f timesteps/s", l, frames / secs);
    bar.update(1, status);
    if (step % a.checkpoint_every == 0 || step == total_steps || out_of_time) {
      const double vl = validate();
      checks_csv
          << step << "," << loss_sum / static_cast<double>(loss_n) << "," << vl << ","
          << std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count()
          << "\n";
      checks_csv.flush();
      steps_csv.flush();
      loss_sum = 0, loss_n = 0;
      save();
    }
  }
  bar.finish();
  if (!fs::exists(ckpt)) save();  // --max-steps 0: the initial model, so rollout has one
  std::printf(
      "trained %lld steps in %.1f s of optimizer steps%s; checkpoint %s (statistics "
      "inside; also %s)\n",
      static_cast<long long>(step), trained_seconds, out_of_time ? " (--max-seconds reached)" : "",
      ckpt.c_str(), stats_path.c_str());
  return 0;
}

}  // namespace hopnet_cli
