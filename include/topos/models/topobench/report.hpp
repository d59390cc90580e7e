// topos/models/topobench/report.hpp
// A folder of TopoBench runs (std only): runs.csv (one row per finished run, resumable: a runner
// started again on the same folder skips the runs it holds), curves.csv (every run's validation
// checks), summary.csv (mean and std per cell), index.html (the table, the time per cell and the
// learning curves), table.md (the table in Markdown) and baselines.csv (the majority classifier
// per dataset and split), each rewritten atomically after every run. Cells are (model, dataset);
// the models named first (the table's: table_model_names() of table_models.hpp) and the table's
// datasets come first, in their order, others after them.
//   RunsFolder folder("out");
//   if (!folder.done("GIN2", "MUTAG", 0)) folder.add(run.result, run.curve);
#pragma once

#include "topos/config.hpp"
#include "topos/models/topobench/protocol.hpp"

#include <algorithm>
#include <array>
#include <cstdint>
#include <filesystem>
#include <iomanip>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

namespace topos::models::topobench {

/// Cells that did not run, with the reason (model, dataset, reason): shown in the table.
using NotRun = std::vector<std::array<std::string, 3>>;

/// Every run's validation curve, one file: model,dataset,split_seed,epoch,loss,val_accuracy.
inline const char* curves_header() {
  return "model,dataset,split_seed,epoch,loss,val_accuracy\n";
}

/// curves.csv's rows of one run.
std::string format_curve(const RunResult& r, const std::vector<Check>& curve);

using Curves = std::map<std::tuple<std::string, std::string, std::int64_t>,
                        std::pair<std::vector<int>, std::vector<double>>>;

/// Per (model, dataset, split seed): the checks' epochs and validation accuracies of curves.csv's
/// `text` (its header checked); a malformed row is an error naming `file` and the line.
Curves parse_curves(const std::string& text, const std::string& file);

std::string html_escape(const std::string& s);

/// table.md: the table in Markdown (models as rows, datasets as columns, mean ± std and the
/// number of runs where fewer than five), for docs/topobench.md. Rows: the models of
/// `model_order` that have a cell, in that order, then the others as they first appear.
std::string table_markdown(const std::vector<RunResult>& runs, const NotRun& not_run,
                           const std::vector<std::string>& model_order = {});

/// index.html: the table (mean ± std over the splits, runs, time per cell) and, per cell, the
/// validation accuracy of every split against the check (`curves`: curves.csv's text).
std::string report_html(const std::vector<RunResult>& runs, const NotRun& not_run,
                        const std::string& curves, const std::string& curves_file,
                        const std::vector<std::string>& model_order = {});

/// A runs folder: what an earlier start left (checked: a malformed runs.csv or curves.csv is an
/// error naming it), and every finished run added at once, all files rewritten atomically.
class RunsFolder {
 public:
  /// The reports' rows start with the models of `model_order` (table_markdown).
  explicit RunsFolder(std::filesystem::path out, std::vector<std::string> model_order = {});

  const std::filesystem::path& path() const { return out_; }
  const std::vector<RunResult>& runs() const { return runs_; }
  bool done(const std::string& model, const std::string& dataset, std::int64_t seed) const {
    return std::any_of(runs_.begin(), runs_.end(), [&](const RunResult& r) {
      return r.model == model && r.dataset == dataset && r.split_seed == seed;
    });
  }

  /// A finished run and its checks: curves.csv and runs.csv, then the reports.
  void add(const RunResult& run, const std::vector<Check>& curve, const NotRun& not_run = {});

  /// summary.csv, index.html and table.md of the runs so far.
  void write_reports(const NotRun& not_run = {}) const;

  /// The majority classifier's test accuracy per (dataset, split seed): baselines.csv.
  const std::map<std::pair<std::string, std::int64_t>, double>& baselines() const {
    return baselines_;
  }
  /// A split's majority baseline (majority_accuracy): baselines.csv rewritten.
  void add_baseline(const std::string& dataset, std::int64_t seed, double accuracy);

 private:
  std::filesystem::path out_;
  std::vector<std::string> model_order_;
  std::vector<RunResult> runs_;
  std::string curves_;
  std::map<std::pair<std::string, std::int64_t>, double> baselines_;
};

}  // namespace topos::models::topobench

#ifdef TOPOS_HEADER_ONLY
#include "topos/models/topobench/report-inl.hpp"
#endif
