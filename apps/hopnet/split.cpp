// hopnet split: the reference 80/10/10 split of a seed set or a dataset.
#include "commands.hpp"

namespace hopnet_cli {
namespace {

struct SplitArgs {
  std::string seeds, data, out, part;
};

// The reference split of a seed set (or of a dataset's scenes), as JSON or one part as a list.
int run_split(const SplitArgs& a) {
  if (a.seeds.empty() == a.data.empty()) throw data::DataError("give either --seeds or --data");
  const auto ids =
      a.seeds.empty() ? data::Dataset::open(a.data).ids() : data::parse_seed_range(a.seeds);
  const auto split = data::reference_split(ids);
  if (!a.part.empty()) {
    const auto part = data::split_part(split, a.part, ids);
    for (std::size_t i = 0; i < part.size(); ++i)
      std::printf("%s%lld", i ? "," : "", static_cast<long long>(part[i]));
    std::printf("\n");
  }
  if (!a.out.empty()) write_json_atomic(data::split_json(split), a.out);
  if (a.part.empty() && a.out.empty()) std::printf("%s\n", data::split_json(split).dump().c_str());
  return 0;
}

}  // namespace

Command add_split(CLI::App& app) {
  auto args = std::make_shared<SplitArgs>();
  auto& sp = *args;
  auto* cs = app.add_subcommand(
      "split", "the reference 80/10/10 split of a seed set or dataset (docs/datasets.md)");
  cs->add_option("--seeds", sp.seeds, "seed set, e.g. 1-1200");
  cs->add_option("--data", sp.data, "or: a dataset folder")->check(CLI::ExistingDirectory);
  cs->add_option("--part", sp.part, "print one part as a comma-separated list: train, val or test");
  cs->add_option("--out", sp.out,
                 "write the split as JSON (the --split-file of train and evaluate)");
  return {cs, [args] { return run_split(*args); }};
}

}  // namespace hopnet_cli
