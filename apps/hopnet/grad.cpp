// hopnet grad: the loss of one training trajectory and its gradient with respect to every
// parameter, written as NumPy arrays by the reference's parameter names (for checking training
// parity against the reference implementation).
#include "commands.hpp"

namespace hopnet_cli {
namespace {

struct GradArgs {
  std::string checkpoint, stats, scene, assets, mode = "reference", out, collisions;
  bool no_collisions_json = false;
  VariantArgs variant;
  std::int64_t chunk = 0;
  double memory_budget_mb = kDefaultMemoryBudgetMb;
};

int run_grad(const GradArgs& a) {
  namespace fs = std::filesystem;
  const FeatureMode mode = feature_mode_from_string(a.mode);
  const auto opened = open_checkpoint(a.checkpoint, open_options(a.variant, a.stats, mode));
  const auto& hop = hopnet_model(opened, "grad");
  auto model = hop.net();
  model->train();
  const Normalizer& norm = *hop.normalizer();
  MeshLibrary lib(a.assets);
  const auto kubric = data::read_kubric_metadata(a.scene);
  const Scene scene = make_scene(kubric, lib);
  const auto g = make_geometry(scene, model->options.lifting());
  std::optional<ContactsByFrame> given;
  const auto coll = a.collisions.empty() && mode == FeatureMode::reference && !a.no_collisions_json
                        ? collisions_beside(kubric)
                        : a.collisions;
  if (!coll.empty()) given = read_collisions_json(coll);
  const auto tf = trajectory_frames(scene, g, model->options.collision_radius(), 0.0, 2, -1,
                                    given ? &*given : nullptr);
  const auto chunk = a.chunk > 0 ? a.chunk
                                 : auto_chunk(g, tf, model->options.hidden(),
                                              a.memory_budget_mb * 1024.0 * 1024.0);
  const auto chunks = make_training_chunks(g, tf, norm, chunk);
  std::printf("grad: %zu timesteps in %zu chunk(s) of <= %lld, mode %s, contacts %s\n",
              tf.frames.size(), chunks.size(), static_cast<long long>(chunk), to_string(mode),
              coll.empty() ? "detected" : coll.c_str());

  model->zero_grad();
  std::vector<double> per_timestep;
  backward_trajectory(*model, chunks, norm, &per_timestep);
  // The reference's float32 total: the timesteps' losses added in order.
  float total = 0;
  for (double l : per_timestep) total += static_cast<float>(l);

  fs::create_directories(fs::path(a.out) / "grads");
  double sq = 0;
  for (const auto& p : model->named_parameters()) {
    const auto grad = p.value().grad().defined()
                          ? p.value().grad().detach().to(torch::kCPU).contiguous()
                          : torch::zeros_like(p.value(), torch::kCPU);
    sq += grad.to(torch::kDouble).pow(2).sum().item<double>();
    const auto sizes = grad.sizes();
    data::write_npy(
        (fs::path(a.out) / "grads" / (reference_parameter_name(p.key()) + ".npy")).string(),
        std::vector<std::int64_t>(sizes.begin(), sizes.end()), grad.data_ptr<float>());
  }
  data::write_npy((fs::path(a.out) / "loss_per_timestep.npy").string(),
                  {static_cast<std::int64_t>(per_timestep.size())}, per_timestep.data());
  data::write_npy((fs::path(a.out) / "loss_total.npy").string(), {}, &total);
  std::printf(
      "loss %.7g (mean per timestep %.7g), gradient norm %.7g over %lld parameters; wrote %s\n",
      static_cast<double>(total),
      static_cast<double>(total) / static_cast<double>(per_timestep.size()), std::sqrt(sq),
      static_cast<long long>(model->num_parameters()), a.out.c_str());
  return 0;
}

}  // namespace

std::string collisions_beside(const data::KubricScene& scene) {
  return collisions_json_beside(scene.source);
}

Command add_grad(CLI::App& app) {
  auto args = std::make_shared<GradArgs>();
  auto& gr = *args;
  auto* c = app.add_subcommand("grad",
                               "loss and gradient of one training trajectory: loss_total.npy, "
                               "loss_per_timestep.npy, grads/<reference name>.npy");
  c->add_option("--checkpoint", gr.checkpoint, "model checkpoint (topos or reference .pt)")
      ->required()
      ->check(CLI::ExistingFile);
  c->add_option("--stats", gr.stats, "normalisation statistics (JSON)")
      ->required()
      ->check(CLI::ExistingFile);
  c->add_option("--scene", gr.scene, "Kubric metadata.json, or the folder holding it")
      ->required()
      ->check(CLI::ExistingPath);
  c->add_option("--assets", gr.assets,
                "meshes in the KuBasic layout (<shape>/collision_geometry.obj); built-in shapes "
                "when omitted");
  c->add_option("--mode", gr.mode,
                "reference (the reference's features and autograd) or native (true gradient)")
      ->capture_default_str();
  c->add_option("--collisions", gr.collisions,
                "contacts of every frame (default: collisions.json beside the scene, reference "
                "mode; else detected)");
  c->add_flag("--no-collisions-json", gr.no_collisions_json,
              "detect the contacts even where a collisions.json is present");
  c->add_option("--chunk", gr.chunk, "timesteps per forward/backward (0: from --memory-budget-mb)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  c->add_option("--memory-budget-mb", gr.memory_budget_mb, "activation memory for one chunk")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  c->add_option("--out", gr.out, "output folder")->required();
  add_variant_options(c, gr.variant, /*with_config=*/false);
  return {c, [args] { return run_grad(*args); }};
}

}  // namespace hopnet_cli
