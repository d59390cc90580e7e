// apps/tdl/main.cpp
// tdl: topological deep learning on TDL cases (the tdl-golden format): computing a case's
// operators with topos and (built with LibTorch) running TopoModelX models: forward, grad, and
// training on the karate club (train) and on batched point-cloud complexes (classify). Each
// subcommand registers itself here, one line each; errors are one line on stderr and exit
// status 1.
#include "commands.hpp"

#include <cstdio>
#include <exception>

int main(int argc, char** argv) {
  CLI::App app{"tdl: topos on TDL cases (TopoNetX/TopoModelX parity format)"};
  app.require_subcommand(1);
  tdl_cli::Run run;
  tdl_cli::register_operators(app, run);
  tdl_cli::register_lift(app, run);
#ifdef TOPOS_TDL_WITH_NN
  tdl_cli::register_forward(app, run);
  tdl_cli::register_grad(app, run);
  tdl_cli::register_train(app, run);
  tdl_cli::register_classify(app, run);
  tdl_cli::register_topobench(app, run);
#endif
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  try {
    return run ? run() : 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tdl: error: %s\n", e.what());
    return 1;
  }
}
