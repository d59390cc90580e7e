// hopnet export: a trained model for Python (torch.load-able, weights_only-safe).
#include "commands.hpp"

namespace hopnet_cli {
namespace {

struct ExportArgs {
  std::string checkpoint, stats, out, names = "reference";
};

// A trained model for Python: {"format", "config", "state_dict", "normalization"} in torch.save's
// format (weights_only-safe). With reference names the state dict loads into the authors'
// HOPNet class (load_state_dict); normalisation statistics are float64 tensors by key.
int run_export(const ExportArgs& a) {
  if (a.names != "reference" && a.names != "topos")
    throw std::invalid_argument("unknown --names '" + a.names + "' (reference, topos)");
  sim::OpenOptions how;
  how.require_statistics = false;  // --stats, when given, is exported as it is
  const auto checkpoint = open_checkpoint(a.checkpoint, how);
  auto model = hopnet_model(checkpoint, "export").net();
  c10::Dict<std::string, torch::Tensor> state;
  for (const auto& p : model->named_parameters())
    state.insert(a.names == "reference"
                     ? reference_parameter_name(p.key(), model->options.architecture())
                     : p.key(),
                 p.value().detach().cpu().contiguous());
  c10::impl::GenericDict config(c10::StringType::get(), c10::AnyType::get());
  const auto& o = model->options;
  config.insert("hidden", o.hidden());
  config.insert("mlp_layers", static_cast<std::int64_t>(o.mlp_layers()));
  config.insert("num_layers", static_cast<std::int64_t>(o.num_layers()));
  config.insert("activation", nn::activation_name(o.activation()));
  config.insert("mode", std::string(to_string(o.mode())));
  config.insert("architecture", std::string(to_string(o.architecture())));
  config.insert("center_mass_distance", o.center_mass_distance());
  config.insert("collision_radius", o.collision_radius());
  c10::impl::GenericDict top(c10::StringType::get(), c10::AnyType::get());
  top.insert("format", std::string("topos-hopnet-export/1"));
  top.insert("parameter_names", a.names);
  top.insert("config", config);
  top.insert("state_dict", state);
  if (!a.stats.empty()) {
    const auto stats = read_stats_json(a.stats);
    c10::Dict<std::string, torch::Tensor> norm;
    for (const auto& [k, n] : stats.keys()) {
      norm.insert(k + "_mean", torch::tensor(stats.mean.at(k), torch::kDouble));
      norm.insert(k + "_std", torch::tensor(stats.std.at(k), torch::kDouble));
    }
    top.insert("normalization", norm);
  }
  nn::write_torch_file(top, a.out);
  std::printf("wrote %s: %zu tensors (%s names)%s, %lld parameters\n", a.out.c_str(), state.size(),
              a.names.c_str(), a.stats.empty() ? "" : " and normalisation statistics",
              static_cast<long long>(model->num_parameters()));
  return 0;
}

}  // namespace

Command add_export(CLI::App& app) {
  auto args = std::make_shared<ExportArgs>();
  auto& ex = *args;
  auto* cx = app.add_subcommand("export",
                                "write a model for Python: torch.load(FILE) gives config, "
                                "state_dict (reference names) and statistics");
  cx->add_option("--checkpoint", ex.checkpoint, "a topos or reference checkpoint")
      ->required()
      ->check(CLI::ExistingFile);
  cx->add_option("--stats", ex.stats, "normalisation statistics to include")
      ->check(CLI::ExistingFile);
  cx->add_option("--names", ex.names,
                 "parameter names: reference (the authors' HOPNet class) or topos")
      ->capture_default_str();
  cx->add_option("--out", ex.out, "file to write")->required();
  return {cx, [args] { return run_export(*args); }};
}

}  // namespace hopnet_cli
