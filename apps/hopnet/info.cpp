// hopnet info: a checkpoint's or a configuration's variant, parameter count and schedule
// (Simulator::describe; for the baselines also the parameters per module).
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
  auto o = open_options(a.variant, "", std::nullopt);
  o.require_statistics = false;
  std::unique_ptr<sim::Simulator> model;
  if (!a.checkpoint.empty()) {
    auto opened = open_checkpoint(a.checkpoint, o);
    std::cout << "checkpoint: " << a.checkpoint << "\nformat: " << opened.format << "\n";
    model = std::move(opened.simulator);
  } else {
    model = sim::make_model(a.variant.config, o);
  }
  model->describe(std::cout);
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
