// apps/tdl/commands.hpp
// The tdl program's subcommands. Each lives in its own translation unit (but forward and grad,
// which share cases.cpp) and registers itself on the CLI11 app with one function; main.cpp calls
// them, one line per subcommand, and runs the callback the parsed subcommand set.
#pragma once

#include <CLI/CLI.hpp>

#include <functional>

namespace tdl_cli {

/// What a subcommand runs after parsing; returns the exit status.
using Run = std::function<int()>;

/// tdl operators --case DIR --out OUTDIR: every operator of DIR/operators.json as
/// OUTDIR/<name>.npy.
void register_operators(CLI::App& app, Run& run);
/// tdl lift --data-dir DIR --dataset NAME --lifting clique|cycle|khop: TopoBench's lifting of
/// every graph of a dataset; the total cells per rank and the time as one JSON object.
void register_lift(CLI::App& app, Run& run);

#ifdef TOPOS_TDL_WITH_NN
/// tdl forward --case DIR --out OUTDIR: the case's model on its inputs, OUTDIR/<output>.npy.
void register_forward(CLI::App& app, Run& run);
/// tdl grad --case DIR --out OUTDIR: OUTDIR/<param>.npy, the gradients of sum(out * R).
void register_grad(CLI::App& app, Run& run);
/// tdl train --out OUTDIR: node classification on Zachary's karate club (SCN2, SCCNN, UniGCNII).
void register_train(CLI::App& app, Run& run);
/// tdl classify --out OUTDIR: point clouds classified by their holes, batched complexes through a
/// schedule.
void register_classify(CLI::App& app, Run& run);
/// tdl topobench --data-dir DIR --models ... --datasets ... --out OUT: TopoBench's table.
void register_topobench(CLI::App& app, Run& run);
#endif

}  // namespace tdl_cli
