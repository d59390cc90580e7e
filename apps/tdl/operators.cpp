// apps/tdl/operators.cpp
// `tdl operators --case DIR --out OUTDIR`: builds the case's domain from DIR/complex.json and
// every operator of DIR/operators.json from its op/args (topos/data/tdl_case.hpp), then writes
// each as OUTDIR/<name>.npy, dense float32, atomically. Everything is computed before the first
// file is written, so a bad case leaves OUTDIR untouched.
#include "commands.hpp"

#include "topos/data/npy.hpp"
#include "topos/data/tdl_case.hpp"

#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace tdl_cli {

namespace {

struct OperatorsArgs {
  std::string case_dir, out;
};

int run_operators(const OperatorsArgs& a) {
  namespace fs = std::filesystem;
  const topos::data::Operators ops = topos::data::compute_operators(a.case_dir);
  fs::create_directories(a.out);
  for (const std::string& name : ops.order) {
    if (name.empty() || name.find('/') != std::string::npos ||
        name.find('\\') != std::string::npos || name == "." || name == "..") {
      throw topos::data::DataError("operator name '" + name + "' cannot be a file name");
    }
  }
  for (const std::string& name : ops.order) {
    const topos::data::SparseOp& m = ops.by_name.at(name);
    std::vector<float> dense(static_cast<std::size_t>(m.rows() * m.cols()), 0.0f);
    for (Eigen::Index i = 0; i < m.outerSize(); ++i)
      for (topos::data::SparseOp::InnerIterator it(m, i); it; ++it)
        dense[static_cast<std::size_t>(it.row() * m.cols() + it.col())] =
            static_cast<float>(it.value());
    topos::data::write_npy((fs::path(a.out) / (name + ".npy")).string(), {m.rows(), m.cols()},
                           dense.data());
  }
  std::printf("wrote %zu operators to %s\n", ops.order.size(), a.out.c_str());
  return 0;
}

}  // namespace

void register_operators(CLI::App& app, Run& run) {
  auto args = std::make_shared<OperatorsArgs>();
  CLI::App* c = app.add_subcommand("operators",
                                   "compute every operator of DIR/operators.json from "
                                   "DIR/complex.json; write OUTDIR/<name>.npy (dense float32)");
  c->add_option("--case", args->case_dir, "case folder (complex.json, operators.json)")
      ->required()
      ->check(CLI::ExistingDirectory);
  c->add_option("--out", args->out, "output folder (created if missing)")->required();
  c->callback([args, &run] { run = [args] { return run_operators(*args); }; });
}

}  // namespace tdl_cli
