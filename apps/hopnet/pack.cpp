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

void pack_scenes(const std::filesystem::path& from, const std::vector<std::int64_t>& ids,
                 const std::string& out) {
  std::vector<data::KubricScene> scenes;
  ProgressBar bar("pack", static_cast<std::int64_t>(ids.size()), "scenes");
  for (auto id : ids) {
    scenes.push_back(data::read_kubric_metadata(from / std::to_string(id)));
    scenes.back().seed = id;
    bar.update();
  }
  bar.finish();
  if (std::filesystem::exists(std::filesystem::path(out) / "dataset.json"))
    throw data::DataError(
        out + ": already holds a topos dataset (dataset.json); remove it or write elsewhere");
  // The reference's contacts (collisions.json), where a scene has them: reference-mode training
  // uses them as the reference does. Written before dataset.json, which comes last.
  std::size_t with_contacts = 0;
  for (auto id : ids) {
    const auto src = from / std::to_string(id) / "collisions.json";
    if (!std::filesystem::exists(src)) continue;
    std::filesystem::create_directories(std::filesystem::path(out) / "collisions");
    io::write_file_atomic(
        (std::filesystem::path(out) / "collisions" / (std::to_string(id) + ".json")).string(),
        data::read_text_file(src));
    ++with_contacts;
  }
  data::write_topos_dataset(scenes, out);
  std::printf(
      "wrote the topos dataset %s (%zu scenes): dataset.json, positions.npy, quaternions.npy",
      out.c_str(), scenes.size());
  if (with_contacts) std::printf(", collisions/ (%zu scenes' collisions.json)", with_contacts);
  std::printf("\n");
}

Command add_pack(CLI::App& app) {
  auto args = std::make_shared<PackArgs>();
  auto& pa = *args;
  auto* cp =
      app.add_subcommand("pack", "convert a folder of Kubric scene folders into a topos dataset");
  cp->add_option("--data", pa.data, "Kubric scene folders (<seed>/metadata.json)")
      ->required()
      ->check(CLI::ExistingDirectory);
  cp->add_option("--seeds", pa.seeds, "only these seeds (default: every scene folder)");
  cp->add_option("--out", pa.out, "folder for dataset.json, positions.npy, quaternions.npy")
      ->required();
  return {cp, [args] { return run_pack(*args); }};
}

}  // namespace hopnet_cli
