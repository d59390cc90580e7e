// hopnet plot: the training curves of a run (its steps.csv and epochs.csv) as an HTML page.
#include "commands.hpp"
#include "report.hpp"

namespace hopnet_cli {
namespace {

struct PlotArgs {
  std::string log, out;
};

int run_plot(const PlotArgs& a) {
  hopnet_web::require_js_libraries();
  const auto log = hopnet_report::read_training_log(a.log);
  const std::string out =
      a.out.empty() ? (std::filesystem::path(a.log) / "training.html").string() : a.out;
  hopnet_report::write_training_report(out, log);
  std::printf("%zu steps, %zu epochs; wrote %s\n", log.step.size(), log.epoch.size(), out.c_str());
  return 0;
}

}  // namespace

Command add_plot(CLI::App& app) {
  auto args = std::make_shared<PlotArgs>();
  auto* cp = app.add_subcommand(
      "plot", "draw a run's training curves (steps.csv, epochs.csv) as an HTML page");
  cp->add_option("--log", args->log, "the run's output folder (hopnet train --out)")
      ->required()
      ->check(CLI::ExistingDirectory);
  cp->add_option("--out", args->out, "the page to write (default: <log>/training.html)");
  return {cp, [args] { return run_plot(*args); }};
}

}  // namespace hopnet_cli
