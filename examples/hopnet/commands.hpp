// examples/hopnet/commands.hpp
// The hopnet program's subcommands, one file each (info.cpp, train.cpp, ...). Each add_<name>
// declares its options on the program and returns the subcommand with the function that runs it
// once the command line is parsed; main.cpp only lists them. Also the program's shared includes
// (precompiled: see examples/CMakeLists.txt) and the few helpers several subcommands use.
#pragma once

#include "topos/data/dataset.hpp"
#include "topos/data/movi_generator.hpp"
#include "topos/io/atomic_file.hpp"
#include "topos/models/hopnet/training.hpp"
#include "topos/nn/cpu.hpp"
#include "topos/util/progress.hpp"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <functional>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

namespace hopnet_cli {

using namespace topos;
using namespace topos::hopnet;

/// A registered subcommand: its CLI11 app and what runs it.
struct Command {
  CLI::App* app;
  std::function<int()> run;
};

Command add_info(CLI::App& app);
Command add_init(CLI::App& app);
Command add_export(CLI::App& app);
Command add_generate(CLI::App& app);
Command add_pack(CLI::App& app);
Command add_split(CLI::App& app);
Command add_train(CLI::App& app);
Command add_evaluate(CLI::App& app);
Command add_rollout(CLI::App& app);

inline void write_json_atomic(const nlohmann::json& j, const std::string& path) {
  write_file_atomic(path, j.dump() + "\n");
}

/// Reads Kubric scene folders `from/<id>` and writes them as one topos dataset (pack, generate).
void pack_scenes(const std::filesystem::path& from, const std::vector<std::int64_t>& ids,
                 const std::string& out);

}  // namespace hopnet_cli
