// hopnet pack: Kubric scene folders into one topos dataset.
#include "commands.hpp"

namespace hopnet_cli {
namespace {

struct PackArgs {
  std::string data, out, seeds;
};

int run_pack(const PackArgs& a) {
  const auto ids = a.seeds.empty() ? data::list_scenes(a.data) : data::parse_seed_range(a.seeds);
  pack_scenes(a.data, ids, a.out);
  return 0;
}

}  // namespace

void pack_scenes(const std::filesystem::path& from, const std::vector<std::int64_t>& ids, const std::string& out) {
  std::vector<data::KubricScene> scenes;
  ProgressBar bar("pack", static_cast<std::int64_t>(ids.size()), "scenes");
  for (auto id : ids) {
    scenes.push_back(data::read_kubric_metadata(from / std::to_string(id)));
    scenes.back().seed = id;
    bar.update();
  }
  bar.finish();
  data::write_topos_dataset(scenes, out);
  std::printf("wrote the topos dataset %s (%zu scenes): dataset.json, positions.npy, quaternions.npy\n", out.c_str(), scenes.size());
}

Command add_pack(CLI::App& app) {
  auto args = std::make_shared<PackArgs>();
  auto& pa = *args;
  auto* cp = app.add_subcommand("pack", "convert a folder of Kubric scene folders into a topos dataset");
  cp->add_option("--data", pa.data, "Kubric scene folders (<seed>/metadata.json)")->required()->check(CLI::ExistingDirectory);
  cp->add_option("--seeds", pa.seeds, "only these seeds (default: every scene folder)");
  cp->add_option("--out", pa.out, "folder for dataset.json, positions.npy, quaternions.npy")->required();
  return {cp, [args] { return run_pack(*args); }};
}

}  // namespace hopnet_cli
