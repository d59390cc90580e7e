// hopnet: the HOPNet program of topos. Subcommands (one file each, see commands.hpp): info, init,
// export (models); generate, pack, split (datasets); grad, train, evaluate, rollout, stats, plot.
// Every subcommand has --help; errors print one line and exit with status 1, leaving no
// half-written output.
#include "commands.hpp"

int main(int argc, char** argv) {
  using namespace hopnet_cli;
  CLI::App app{
      "hopnet: HOPNet (Wei & Fink) on topos: generate MOVi data, train, evaluate, roll out, "
      "export"};
  app.require_subcommand(1);
  int threads = 1, blas_threads = 0;
  app.add_option("--threads", threads, "LibTorch intra-op threads (1 is fastest here)")
      ->capture_default_str();
  app.add_option("--blas-threads", blas_threads,
                 "BLAS threads (default: all cores for train, 1 otherwise)");
  const std::vector<Command> commands{add_info(app),     add_init(app),  add_export(app),
                                      add_generate(app), add_pack(app),  add_split(app),
                                      add_grad(app),     add_train(app), add_evaluate(app),
                                      add_rollout(app),  add_stats(app), add_plot(app)};
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  try {
    // Training's large batched matmuls want BLAS threads; a rollout's small ones do not.
    const bool training = app.got_subcommand("train") || app.got_subcommand("grad");
    topos::nn::set_cpu_threads(threads, blas_threads > 0 ? blas_threads : (training ? 0 : 1));
    if (training) topos::nn::keep_freed_memory();
    for (const auto& c : commands)
      if (c.app->parsed()) return c.run();
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
  return 1;
}
