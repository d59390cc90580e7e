// examples/tdl/forward.cpp
// tdl forward --case DIR --out OUTDIR: runs a golden case's model (eval mode) and writes
// OUTDIR/<output>.npy for every output case.json names.
#include "zoo_commands.hpp"

#include <iostream>
#include <memory>

namespace tdl_cli {

void register_forward(CLI::App& app, Run& run) {
  auto o = std::make_shared<CaseOptions>();
  auto* cmd = app.add_subcommand(
      "forward", "run a case's TopoModelX model on its inputs and write its outputs as .npy");
  add_case_options(cmd, *o);
  cmd->callback([o, &run] {
    run = [o] {
      auto c = open_case(*o);
      torch::NoGradGuard no_grad;
      const auto out = topos::models::run_case(c);
      for (const auto& name : c.outputs)
        topos::models::write_npy_tensor(std::filesystem::path(o->out_dir) / (name + ".npy"),
                                        out.at(name));
      std::cout << c.model.name << ": wrote " << c.outputs.size() << " outputs to " << o->out_dir
                << "\n";
      return 0;
    };
  });
}

}  // namespace tdl_cli
