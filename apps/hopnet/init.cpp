// hopnet init: a freshly initialised model as a topos checkpoint.
#include "commands.hpp"

namespace hopnet_cli {
namespace {

struct InitArgs {
  std::string out, mode = "reference";
  std::int64_t hidden = 0;  // 0: the configuration's
  int mlp_layers = 0, num_layers = 0;
  VariantArgs variant;
  std::uint64_t seed = 0;
};

int run_init(const InitArgs& a) {
  torch::manual_seed(a.seed);
  HopnetOptions o =
      variant_options(a.variant, HopnetOptions().mode(feature_mode_from_string(a.mode)));
  if (a.hidden > 0) o.hidden(a.hidden);
  if (a.mlp_layers > 0) o.mlp_layers(a.mlp_layers);
  if (a.num_layers > 0) o.num_layers(a.num_layers);
  Hopnet net(o);
  save_hopnet(*net, a.out);
  std::cout << "wrote " << a.out << " (" << variant_name(o) << ", " << net->num_parameters()
            << " parameters, PyTorch default initialisation, seed " << a.seed << ")\n";
  return 0;
}

}  // namespace

Command add_init(CLI::App& app) {
  auto args = std::make_shared<InitArgs>();
  auto& in = *args;
  auto* cn = app.add_subcommand("init", "write a freshly initialised model (a topos checkpoint)");
  cn->add_option("--out", in.out, "checkpoint to write")->required();
  add_variant_options(cn, in.variant, true);
  cn->add_option("--hidden", in.hidden, "hidden width (default: the configuration's)")
      ->check(CLI::PositiveNumber);
  cn->add_option("--mlp-layers", in.mlp_layers,
                 "Linear layers per MLP (default: the configuration's)")
      ->check(CLI::PositiveNumber);
  cn->add_option("--num-layers", in.num_layers,
                 "message-passing layers (default: the configuration's)")
      ->check(CLI::PositiveNumber);
  cn->add_option("--mode", in.mode, "reference or native dual encoding")->capture_default_str();
  cn->add_option("--seed", in.seed, "initialisation seed")->capture_default_str();
  return {cn, [args] { return run_init(*args); }};
}

}  // namespace hopnet_cli
