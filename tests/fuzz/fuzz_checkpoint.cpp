// Fuzz harness: torch files (nn/serialization.hpp parse_tensor_dict: the zip archive, the
// pickle, the tensors' extents) and what `hopnet info/evaluate` do with the dict: the HOPNet
// configuration and loading it by name (models/hopnet/model.hpp).
#include "fuzz_target.hpp"

#include "topos/models/hopnet/model.hpp"

TOPOS_FUZZ_TARGET(checkpoint) {
  using namespace topos_fuzz;
  std::map<std::string, torch::Tensor> dict;
  try {
    dict = topos::nn::parse_tensor_dict(reinterpret_cast<const char*>(data), size, source());
  } catch (const std::runtime_error& e) {
    expect_error(e.what());
    return 0;
  }
  for (const auto& [name, t] : dict) {
    // Every element must be readable (ASan reports a read past the storage).
    if (t.numel() > 0 && t.numel() < (1 << 20) && t.is_floating_point())
      (void)t.to(torch::kDouble).sum().item<double>();
  }
  try {
    const auto opt = topos::models::hopnet::checkpoint_options(dict, source());
    // Building the network costs its parameters: only small ones (the configuration's limits
    // are the config harness's).
    if (opt.hidden() <= 16 && opt.num_layers() <= 2 && opt.mlp_layers() <= 3)
      (void)topos::models::hopnet::load_hopnet(dict, source());
  } catch (const std::runtime_error& e) {
    expect_error(e.what());
  }
  return 0;
}
