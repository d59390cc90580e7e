// hopnet info: a checkpoint's configuration, parameter count and schedule.
#include "commands.hpp"

namespace hopnet_cli {
namespace {

struct InfoArgs {
  std::string checkpoint;
};

int run_info(const InfoArgs& a) {
  const auto dict = nn::read_tensor_dict(a.checkpoint);
  auto model = load_hopnet(dict, a.checkpoint);
  std::cout << "checkpoint: " << a.checkpoint << "\n"
            << "format: " << (is_reference_checkpoint(dict) ? "reference (HOPNet authors' state dict)" : "topos") << "\n"
            << "configuration: " << model->options.to_json().dump() << "\n"
            << "parameters: " << model->num_parameters() << "\n"
            << "schedule:\n" << model->schedule().str();
  return 0;
}

}  // namespace

Command add_info(CLI::App& app) {
  auto args = std::make_shared<InfoArgs>();
  auto& info = *args;
  auto* ci = app.add_subcommand("info", "print a checkpoint's configuration, parameter count and schedule");
  ci->add_option("--checkpoint", info.checkpoint, "a topos or reference (.pt) checkpoint")->required()->check(CLI::ExistingFile);
  return {ci, [args] { return run_info(*args); }};
}

}  // namespace hopnet_cli
