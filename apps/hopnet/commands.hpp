// apps/hopnet/commands.hpp
// The hopnet program's subcommands, one file each (info.cpp, train.cpp, ...). Each add_<name>
// declares its options on the program and returns the subcommand with the function that runs it
// once the command line is parsed; main.cpp only lists them. Also the program's shared includes
// (one unity translation unit: apps/CMakeLists.txt) and the few helpers several subcommands use.
#pragma once

#include "topos/data/dataset.hpp"
#include "topos/data/movi_generator.hpp"
#include "topos/io/atomic_file.hpp"
#include "topos/models/hopnet/training.hpp"
#include "topos/models/hopnet/variants.hpp"
#include "topos/nn/cpu.hpp"
#include "topos/sim/open_model.hpp"
#include "topos/util/csv_log.hpp"
#include "topos/util/progress.hpp"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <functional>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

namespace hopnet_cli {

using namespace topos;
using namespace topos::models::hopnet;

/// A registered subcommand: its CLI11 app and what runs it.
struct Command {
  CLI::App* app;
  std::function<int()> run;
};

Command add_info(CLI::App& app);
Command add_init(CLI::App& app);
Command add_export(CLI::App& app);
Command add_generate(CLI::App& app);
Command add_pack(CLI::App& app);
Command add_split(CLI::App& app);
Command add_grad(CLI::App& app);
Command add_train(CLI::App& app);
Command add_evaluate(CLI::App& app);
Command add_rollout(CLI::App& app);
Command add_stats(CLI::App& app);
Command add_plot(CLI::App& app);

/// The options that pick a member of the HOPNet family (info, init, train, rollout, evaluate).
struct VariantArgs {
  std::string config, activation;
  double collision_radius = 0;  ///< 0: the configuration's (0.1 by default)
};

inline void add_variant_options(CLI::App* app, VariantArgs& v, bool with_config) {
  if (with_config)
    app->add_option("--config", v.config,
                    "variant: presets and/or JSON files, comma-separated (" + preset_names() +
                        "), e.g. nox4 or mlp3,no-cm-distance");
  app->add_option("--activation", v.activation,
                  "relu, gelu, elu or selu (reference checkpoints do not record it)");
  app->add_option("--collision-radius", v.collision_radius, "contact distance d_c (default 0.1)")
      ->check(CLI::PositiveNumber);
}

/// The configuration of --config (standard when empty) with --activation and --collision-radius on
/// top.
inline HopnetOptions variant_options(const VariantArgs& v, const HopnetOptions& base = {}) {
  HopnetOptions o = v.config.empty() ? base : parse_config(v.config, base);
  if (!v.activation.empty()) o.activation(nn::activation_from_string(v.activation));
  if (v.collision_radius > 0) o.collision_radius(v.collision_radius);
  o.validate();
  return o;
}

/// --matmul-precision of the subcommands that roll out (rollout, evaluate).
inline void add_rollout_precision_option(CLI::App* app, std::string& precision) {
  app->add_option("--matmul-precision", precision,
                  "float32 products: highest (float32) or medium (bfloat16 inputs, float32 "
                  "accumulation; --mode native only: reference mode reproduces the published "
                  "model in float32)")
      ->capture_default_str()
      ->check(CLI::IsMember({"highest", "medium"}));
}

/// --cpu-gemm of the subcommands that roll out (rollout, evaluate).
inline void add_rollout_gemm_option(CLI::App* app, std::string& gemm) {
  app->add_option("--cpu-gemm", gemm,
                  "library of the float32 products on the CPU: onednn (oneDNN's sgemm), topos "
                  "(topos's dense kernel), blas (OpenBLAS through LibTorch), or auto (blas in "
                  "reference mode, which then gives the reference's digits; onednn in native "
                  "mode, or topos without oneDNN); they differ in float32 summation order only")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "blas", "onednn", "topos"}));
}

/// Sets the process's library of float32 products for rollouts in `mode` (--cpu-gemm,
/// nn::cpu_gemm_for_rollout) and returns its name.
inline std::string set_rollout_gemm(const std::string& gemm, FeatureMode mode) {
  nn::set_cpu_gemm(
      nn::cpu_gemm_for_rollout(gemm, nn::get_cpu_gemm(), mode == FeatureMode::reference));
  return nn::to_string(nn::get_cpu_gemm());
}

/// Sets the process's matmul precision for rollouts in `mode`: medium with any mode but native
/// is an error saying what to write instead (reference mode stays the published model's numbers).
inline void set_rollout_precision(const std::string& precision, FeatureMode mode) {
  const auto p = nn::matmul_precision_from_string(precision);
  if (p != nn::MatmulPrecision::highest && mode != FeatureMode::native)
    throw std::invalid_argument(
        "--matmul-precision " + precision + " needs --mode native: " + to_string(mode) +
        " mode reproduces the published model and runs in float32 only; write --mode native "
        "--matmul-precision " +
        precision + ", or leave --matmul-precision at highest");
  nn::set_float32_matmul_precision(p);
}

/// The precision as the programs print and record it: medium names the kernels that run its CPU
/// products ("medium (amx)", "medium (avx512-bf16)", "medium (onednn)"; nn::bfloat16_kernels).
inline std::string precision_label(const std::string& precision, bool cpu = true) {
  if (precision == "highest" || !cpu) return precision;
  return precision + " (" + nn::bfloat16_kernels() + ")";
}

/// The options a model is opened with: the variant's --activation and --collision-radius
/// (HOPNet's), the feature mode, and --stats.
inline sim::OpenOptions open_options(const VariantArgs& v, const std::string& stats_path,
                                     std::optional<FeatureMode> mode) {
  sim::OpenOptions o;
  o.stats = stats_path;
  o.mode = mode;
  if (!v.activation.empty()) o.activation = nn::activation_from_string(v.activation);
  if (v.collision_radius > 0) o.collision_radius = v.collision_radius;
  return o;
}

/// A checkpoint opened the one way every subcommand opens one (sim::open_model: read once, its
/// format detected), its notes said on stderr. The model's own options (lifting,
/// collision radius, widths) are the checkpoint's, never a subcommand's defaults.
inline sim::OpenedModel open_checkpoint(const std::string& path, const sim::OpenOptions& o) {
  auto m = sim::open_model(path, o);
  for (const auto& note : m.notes) std::cerr << "note: " << note << "\n";
  return m;
}

/// The HOPNet model of an opened checkpoint, for what only HOPNet does (`what`: the subcommand).
inline HopnetSimulator& hopnet_model(const sim::OpenedModel& m, const std::string& what) {
  auto* h = dynamic_cast<HopnetSimulator*>(m.simulator.get());
  if (!h)
    throw std::invalid_argument(m.path + ": a " + m.simulator->name() + " checkpoint; " + what +
                                " works on HOPNet checkpoints only");
  return *h;
}

// ---- the paper's baselines, FIGNet and MeshGraphNet (baselines.cpp) ----------------------------
struct BaselineTrainArgs {
  std::string data, out, assets, split_file, config, init, lr_schedule = "constant";
  std::int64_t max_steps = -1;
  int epochs = 1, max_frames = 0, batch_timesteps = 64, stats_stride = 8, val_timesteps = 256,
      checkpoint_every = 100;
  double lr = 1e-3;
  double max_seconds = 0;  ///< a wall-time budget for the optimizer steps (0: none)
  std::uint64_t seed = 0;
  bool resume = false;
};
int run_baseline_train(const BaselineTrainArgs& a);

/// A dataset opened for training: its train and val scenes by the reference split (or a split
/// file); no training scene is an error.
struct TrainingData {
  data::Dataset dataset;
  std::vector<std::int64_t> train, val;
};

inline TrainingData open_training_data(const std::string& path, const std::string& split_file) {
  TrainingData d{data::Dataset::open(path), {}, {}};
  const auto& ids = d.dataset.ids();
  const auto split =
      split_file.empty() ? data::reference_split(ids) : data::read_split_json(split_file);
  d.train = data::split_part(split, "train", ids);
  d.val = data::split_part(split, "val", ids);
  if (d.train.empty()) throw data::DataError(path + ": no training scenes");
  return d;
}

inline void write_json_atomic(const nlohmann::json& j, const std::string& path) {
  io::write_file_atomic(path, j.dump() + "\n");
}

/// Activation memory per forward/backward chunk when --chunk is not given (grad, train).
inline constexpr double kDefaultMemoryBudgetMb = 3072;
/// hopnet train --contact-cache-mb: about 2.5 MB a MOVi-A scene, so all of MOVi-A's 1,080 training
/// and validation scenes fit.
inline constexpr double kDefaultContactCacheMb = 4096;

/// The reference's contacts of every frame beside a Kubric scene (collisions.json), or "".
std::string collisions_beside(const data::KubricScene& scene);

/// Reads Kubric scene folders `from/<id>` and writes them as one topos dataset (pack, generate).
void pack_scenes(const std::filesystem::path& from, const std::vector<std::int64_t>& ids,
                 const std::string& out);

}  // namespace hopnet_cli
