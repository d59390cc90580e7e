// apps/tdl/cases.cpp
// The golden-case subcommands of the model zoo (a few lines each over
// topos/models/zoo/golden_case.hpp, compiled once into topos::zoo):
//   tdl forward --case DIR --out OUTDIR: runs a golden case's model (eval mode) and writes
//     OUTDIR/<output>.npy for every output case.json names.
//   tdl grad --case DIR --out OUTDIR: writes OUTDIR/<param>.npy, the gradient of
//     Σ_outputs Σ(out · R) with R from DIR/grads/_R_<output>.npy, for every parameter.
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
      const auto out = topos::models::zoo::run_case(c);
      for (const auto& name : c.outputs)
        topos::models::write_npy_tensor(std::filesystem::path(o->out_dir) / (name + ".npy"),
                                        out.at(name));
      std::cout << c.model.name << ": wrote " << c.outputs.size() << " outputs to " << o->out_dir
                << "\n";
      return 0;
    };
  });
}

void register_grad(CLI::App& app, Run& run) {
  auto o = std::make_shared<CaseOptions>();
  auto* cmd = app.add_subcommand(
      "grad", "write the parameter gradients of sum(out * R) for a case with grads/");
  add_case_options(cmd, *o);
  cmd->callback([o, &run] {
    run = [o] {
      if (!std::filesystem::is_directory(std::filesystem::path(o->case_dir) / "grads"))
        throw topos::data::DataError(o->case_dir +
                                     ": no grads/ folder (this case has no gradients)");
      auto c = open_case(*o);
      const auto g = topos::models::zoo::case_gradients(c);
      for (const auto& [name, t] : g)
        topos::models::write_npy_tensor(std::filesystem::path(o->out_dir) / (name + ".npy"), t);
      std::cout << c.model.name << ": wrote " << g.size() << " gradients to " << o->out_dir << "\n";
      return 0;
    };
  });
}

}  // namespace tdl_cli
