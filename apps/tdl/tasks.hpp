// apps/tdl/tasks.hpp
// What tdl's training tasks, `tdl train` (karate club) and `tdl classify` (batched point-cloud
// complexes), share: the low-pass filters they propagate with, how an epoch is logged and how
// they write their results.
#pragma once

#include "topos/core/operators.hpp"
#include "topos/core/sparse_matrix.hpp"
#include "topos/io/atomic_file.hpp"
#include "topos/util/progress.hpp"
#include "topos/util/svg_plot.hpp"

#include <filesystem>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace tdl_cli {

/// I - D^{-1/2} L D^{-1/2} (D the row sums of |L|; spectrum in [0, 2]). Where a cell's class
/// agrees with its neighbours', filters must be low-pass: a Laplacian itself is high-pass, and
/// trained on labelled cells it pushes each unlabelled neighbour towards the other class (on
/// the karate club SCN2 and SCCNN with the normalised Laplacians reach 0.29 and 0.54 on the
/// held-out members, below chance; with these filters 0.9 and more).
inline topos::SparseMatrix low_pass_filter(const topos::SparseMatrix& laplacian) {
  const Eigen::VectorXd minus = -Eigen::VectorXd::Ones(laplacian.rows());
  return topos::sparse::add(
      topos::sparse::identity(laplacian.rows()),
      topos::sparse::scale(topos::normalized_laplacian(laplacian), minus, {}));
}

/// An epoch's line of accuracy.csv (`row` first: the model's name and a comma, or nothing) and
/// its progress-bar status.
inline void log_epoch(std::ostringstream& csv, topos::ProgressBar& bar, const std::string& row,
                      int epoch, double loss, double train_accuracy, double test_accuracy) {
  csv << row << epoch << "," << loss << "," << train_accuracy << "," << test_accuracy << "\n";
  std::ostringstream status;
  status << std::fixed << std::setprecision(3) << "loss " << loss << " train " << train_accuracy
         << " test " << test_accuracy;
  bar.update(1, status.str());
}

/// OUT/accuracy.csv (`csv`), OUT/accuracy.svg (the accuracy `curves` per epoch, `ylabel` on the
/// y axis) and OUT/summary.json (`summary`, also printed), each written atomically.
inline void write_task_results(
    const std::string& out, const std::string& csv,
    const std::vector<std::pair<std::string, std::vector<double>>>& curves,
    const std::string& ylabel, const std::string& summary) {
  std::filesystem::create_directories(out);
  const std::filesystem::path dir(out);
  topos::io::write_file_atomic((dir / "accuracy.csv").string(), csv);
  topos::SvgPlotOptions plot;
  plot.xlabel = "epoch";
  plot.ylabel = ylabel;
  plot.ymax = 1;
  plot.x0 = 1;
  topos::io::write_file_atomic((dir / "accuracy.svg").string(), topos::svg_line_plot(curves, plot));
  topos::io::write_file_atomic((dir / "summary.json").string(), summary);
  std::cout << summary << "wrote " << out << "/accuracy.csv, accuracy.svg, summary.json\n";
}

}  // namespace tdl_cli
