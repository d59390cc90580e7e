// hopnet init: a freshly initialised model as a topos checkpoint.
#include "commands.hpp"

namespace hopnet_cli {
namespace {

struct InitArgs {
  std::string out, activation = "relu", mode = "reference";
  std::int64_t hidden = 128;
  int mlp_layers = 2, num_layers = 1;
  std::uint64_t seed = 0;
};

int run_init(const InitArgs& a) {
  torch::manual_seed(a.seed);
  Hopnet net(HopnetOptions().hidden(a.hidden).mlp_layers(a.mlp_layers).num_layers(a.num_layers).activation(nn::activation_from_string(a.activation)).mode(feature_mode_from_string(a.mode)));
  save_hopnet(*net, a.out);
  std::cout << "wrote " << a.out << " (" << net->num_parameters() << " parameters, PyTorch default initialisation, seed " << a.seed << ")\n";
  return 0;
}

}  // namespace

Command add_init(CLI::App& app) {
  auto args = std::make_shared<InitArgs>();
  auto& in = *args;
  auto* cn = app.add_subcommand("init", "write a freshly initialised model (a topos checkpoint)");
  cn->add_option("--out", in.out, "checkpoint to write")->required();
  cn->add_option("--hidden", in.hidden, "hidden width")->capture_default_str()->check(CLI::PositiveNumber);
  cn->add_option("--mlp-layers", in.mlp_layers, "Linear layers per MLP")->capture_default_str()->check(CLI::PositiveNumber);
  cn->add_option("--num-layers", in.num_layers, "message-passing layers")->capture_default_str()->check(CLI::PositiveNumber);
  cn->add_option("--activation", in.activation, "relu, gelu, elu or selu")->capture_default_str();
  cn->add_option("--mode", in.mode, "reference or native dual encoding")->capture_default_str();
  cn->add_option("--seed", in.seed, "initialisation seed")->capture_default_str();
  return {cn, [args] { return run_init(*args); }};
}

}  // namespace hopnet_cli
