// The model-zoo subcommands of the tdl program (forward, grad) and how they get a case's operators.
#pragma once

#include "topos/models/zoo_case.hpp"

#include <CLI/CLI.hpp>

#include <filesystem>
#include <map>
#include <string>

namespace tdl_program {

/// The operators of a case, built from its complex. DEVELOPMENT BRIDGE: until the domains'
/// builder is merged this reads the case's shipped operators; it is the only place that does.
inline std::map<std::string, topos::nn::SparseOperator> case_operators(const std::filesystem::path& dir) { return topos::models::shipped_operators(dir); }

/// Options shared by forward and grad.
struct CaseOptions {
  std::string case_dir, out_dir, state_dict;
  bool intended = false;
};

inline void add_case_options(CLI::App* cmd, CaseOptions& o) {
  cmd->add_option("--case", o.case_dir, "golden case folder (case.json, complex.json, inputs/, state_dict/)")->required();
  cmd->add_option("--out", o.out_dir, "output folder")->required();
  cmd->add_option("--state-dict", o.state_dict, "load the weights from this torch .pt state_dict instead of the case's state_dict/");
  cmd->add_flag("--intended", o.intended, "the papers' behaviour where TopoModelX differs (docs/models.md), not TopoModelX's numbers");
}

inline topos::models::ZooCase open_case(const CaseOptions& o) {
  const std::filesystem::path dir(o.case_dir);
  if (!std::filesystem::is_directory(dir)) throw topos::data::DataError(o.case_dir + ": not a folder");
  auto c = topos::models::load_case(dir, case_operators(dir), !o.intended);
  if (!o.state_dict.empty()) topos::models::load_state_dict(*c.model.module, o.state_dict);
  std::filesystem::create_directories(o.out_dir);
  return c;
}

void add_forward_command(CLI::App& app);
void add_grad_command(CLI::App& app);

}  // namespace tdl_program
