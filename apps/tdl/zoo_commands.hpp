// apps/tdl/zoo_commands.hpp
// What the tdl program's model-zoo subcommands (forward, grad, train) share: the case options and
// opening a case (model, weights, operators built from complex.json). LibTorch; included only by
// their translation units, never by main.cpp or operators.cpp.
#pragma once

#include "commands.hpp"
#include "topos/models/zoo/golden_case.hpp"

#include <filesystem>
#include <string>

namespace tdl_cli {

/// Options shared by forward and grad.
struct CaseOptions {
  std::string case_dir, out_dir, state_dict;
  bool intended = false;
};

inline void add_case_options(CLI::App* cmd, CaseOptions& o) {
  cmd->add_option(
         "--case", o.case_dir,
         "golden case folder (case.json, complex.json, operators.json, inputs/, state_dict/)")
      ->required();
  cmd->add_option("--out", o.out_dir, "output folder")->required();
  cmd->add_option(
      "--state-dict", o.state_dict,
      "load the weights from this torch .pt state_dict instead of the case's state_dict/");
  cmd->add_flag(
      "--intended", o.intended,
      "the papers' behaviour where TopoModelX differs (docs/models.md), not TopoModelX's numbers");
}

inline topos::models::zoo::ZooCase open_case(const CaseOptions& o) {
  const std::filesystem::path dir(o.case_dir);
  if (!std::filesystem::is_directory(dir))
    throw topos::data::DataError(o.case_dir + ": not a folder");
  // The operators are computed after the model and its weights: a bad model or config is named
  // first.
  auto c = topos::models::zoo::load_case(
      dir, [&dir] { return topos::models::zoo::case_operators(dir); }, !o.intended);
  if (!o.state_dict.empty()) topos::models::load_state_dict(*c.model.module, o.state_dict);
  std::filesystem::create_directories(o.out_dir);
  return c;
}

}  // namespace tdl_cli
