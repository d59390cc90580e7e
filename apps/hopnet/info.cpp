// hopnet info: a checkpoint's or a configuration's variant, parameter count and schedule (for
// the baselines also the parameters per module).
#include "commands.hpp"

namespace hopnet_cli {
namespace {

struct InfoArgs {
  std::string checkpoint;
  VariantArgs variant;
};

int run_info(const InfoArgs& a) {
  if (a.checkpoint.empty() == a.variant.config.empty())
    throw std::invalid_argument(
        "info: give either --checkpoint FILE or --config PRESET[,PRESET...]");
  if (a.checkpoint.empty() ? is_baseline_config(a.variant.config)
                           : is_baseline_checkpoint(a.checkpoint))
    return run_baseline_info(a.variant.config, a.checkpoint);
  Hopnet model(nullptr);
  if (!a.checkpoint.empty()) {
    const auto dict = nn::read_tensor_dict(a.checkpoint);
    model = load_hopnet(dict, a.checkpoint,
                        checkpoint_overrides(a.variant, dict, a.checkpoint, std::nullopt));
    std::cout << "checkpoint: " << a.checkpoint << "\n";
    if (const auto arch = reference_architecture(dict))
      std::cout << "format: reference (HOPNet authors' state dict, class " << reference_class(*arch)
                << ", " << dict.size() << " tensors)\n"
                << "variant: " << variant_name(model->options) << " (recognised from the '_"
                << reference_class(*arch)
                << "__' tensor names and shapes; the activation is not recorded)\n";
    else
      std::cout << "format: topos\n"
                << "variant: " << variant_name(model->options) << "\n";
  } else {
    model = Hopnet(variant_options(a.variant));
    std::cout << "variant: " << variant_name(model->options) << "\n";
  }
  std::cout << "configuration: " << model->options.to_json().dump() << "\n"
            << "parameters: " << model->num_parameters() << "\n"
            << "schedule:\n"
            << model->schedule().str();
  return 0;
}

}  // namespace

Command add_info(CLI::App& app) {
  auto args = std::make_shared<InfoArgs>();
  auto& info = *args;
  auto* ci = app.add_subcommand(
      "info", "print a checkpoint's or a configuration's variant, parameter count and schedule");
  ci->add_option("--checkpoint", info.checkpoint, "a topos or reference (.pt) checkpoint")
      ->check(CLI::ExistingFile);
  add_variant_options(ci, info.variant, true);
  return {ci, [args] { return run_info(*args); }};
}

}  // namespace hopnet_cli
