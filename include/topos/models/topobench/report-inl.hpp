// topos/models/topobench/report-inl.hpp
// The runs folder's implementation (topos/models/topobench/report.hpp declares it), compiled once
// into topos::topobench (src/topobench.cpp), or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/data/error.hpp"  // DataError, read_text_file
#include "topos/io/atomic_file.hpp"
#include "topos/models/topobench/report.hpp"
#include "topos/util/svg_plot.hpp"

#include <algorithm>
#include <iomanip>
#include <sstream>
#include <stdexcept>

namespace topos::models::topobench {

TOPOS_INLINE std::string format_curve(const RunResult& r, const std::vector<Check>& curve) {
  std::ostringstream c;
  for (const auto& ch : curve)
    c << r.model << "," << r.dataset << "," << r.split_seed << "," << ch.epoch << "," << ch.loss
      << "," << ch.val_accuracy << "\n";
  return c.str();
}

TOPOS_INLINE Curves parse_curves(const std::string& text, const std::string& file) {
  const std::string header = curves_header();
  if (text.rfind(header, 0) != 0)
    throw std::runtime_error(file + ": expected the header " + header.substr(0, header.size() - 1));
  Curves out;
  std::istringstream in(text);
  std::string line;
  std::getline(in, line);
  for (int n = 2; std::getline(in, line); ++n) {
    std::istringstream f(line);
    std::string m, d, s, e, l, a;
    if (std::getline(f, m, ',') && std::getline(f, d, ',') && std::getline(f, s, ',') &&
        std::getline(f, e, ',') && std::getline(f, l, ',') && std::getline(f, a, ',')) {
      try {
        auto& c = out[{m, d, std::stoll(s)}];
        c.first.push_back(std::stoi(e));
        c.second.push_back(std::stod(a));
        continue;
      } catch (const std::exception&) {  // std::stoi's own message names no file
      }
    }
    throw std::runtime_error(file + ":" + std::to_string(n) + ": malformed row '" + line + "'");
  }
  return out;
}

TOPOS_INLINE std::string html_escape(const std::string& s) {
  std::string o;
  for (char c : s)
    o += c == '<' ? "&lt;" : c == '>' ? "&gt;" : c == '&' ? "&amp;" : std::string(1, c);
  return o;
}

namespace detail {
/// The table's rows (models) and columns (datasets) that have a cell or a not-run entry: those of
/// `model_order` and the table's datasets in their order, then others (a user's backbone or
/// dataset) as they first appear.
inline std::pair<std::vector<std::string>, std::vector<std::string>> table_axes(
    const std::vector<CellSummary>& cells, const NotRun& not_run,
    const std::vector<std::string>& model_order) {
  std::vector<std::string> models, datasets;
  const auto add = [](std::vector<std::string>& v, const std::string& x) {
    if (std::find(v.begin(), v.end(), x) == v.end()) v.push_back(x);
  };
  const auto seen = [&](const std::string& x, bool model) {
    return std::any_of(cells.begin(), cells.end(),
                       [&](const auto& c) { return (model ? c.model : c.dataset) == x; }) ||
           std::any_of(not_run.begin(), not_run.end(),
                       [&](const auto& n) { return n[model ? 0 : 1] == x; });
  };
  for (const auto& m : model_order)
    if (seen(m, true)) add(models, m);
  for (const auto& d : table_datasets())
    if (seen(d.name, false)) datasets.push_back(d.name);
  for (const auto& c : cells) add(models, c.model), add(datasets, c.dataset);
  for (const auto& n : not_run) add(models, n[0]), add(datasets, n[1]);
  return {models, datasets};
}
/// Cell (m, d) of a table: its summary, or null and its not-run entry's reason (null: none).
struct TableCell {
  const CellSummary* summary = nullptr;
  const std::string* not_run = nullptr;
  bool failed() const { return not_run && not_run->find("failed") != std::string::npos; }
};
inline TableCell table_cell(const std::vector<CellSummary>& cells, const NotRun& not_run,
                            const std::string& m, const std::string& d) {
  TableCell t;
  for (const auto& c : cells)
    if (c.model == m && c.dataset == d) t.summary = &c;
  for (const auto& n : not_run)
    if (!t.not_run && n[0] == m && n[1] == d) t.not_run = &n[2];
  return t;
}
}  // namespace detail

TOPOS_INLINE std::string table_markdown(const std::vector<RunResult>& runs, const NotRun& not_run,
                                        const std::vector<std::string>& model_order) {
  const auto cells = summarize(runs);
  const auto [models, datasets] = detail::table_axes(cells, not_run, model_order);
  std::ostringstream o;
  o << "| model |";
  for (const auto& d : datasets) o << " " << d << " |";
  o << "\n|---|";
  for (std::size_t i = 0; i < datasets.size(); ++i) o << "---|";
  o << "\n";
  for (const auto& m : models) {
    o << "| " << m << " |";
    for (const auto& d : datasets) {
      const auto cell = detail::table_cell(cells, not_run, m, d);
      const CellSummary* it = cell.summary;
      if (!it) {
        o << (!cell.not_run ? " - |" : cell.failed() ? " failed |" : " not run (memory) |");
        continue;
      }
      o << " " << std::fixed << std::setprecision(2) << it->mean << " ± " << it->std;
      if (it->runs < 5) o << " (" << it->runs << " runs)";
      o << " |";
    }
    o << "\n";
  }
  return o.str();
}

TOPOS_INLINE std::string report_html(const std::vector<RunResult>& runs, const NotRun& not_run,
                                     const std::string& curves, const std::string& curves_file,
                                     const std::vector<std::string>& model_order) {
  const auto cells = summarize(runs);
  const auto [models, datasets] = detail::table_axes(cells, not_run, model_order);
  double total = 0;
  for (const auto& r : runs) total += r.seconds;
  std::ostringstream h;
  h << "<!doctype html><html><head><meta charset='utf-8'><title>TopoBench on topos</title>"
       "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
       "td,th{border:1px solid #ccc;padding:4px 8px;text-align:center}small{color:#666}"
       "</style></head><body><h1>TopoBench on topos</h1>\n<p>Test accuracy (%), mean ± std over "
       "the splits (numpy's std); below each, the runs and their training time (summed). "
    << runs.size() << " runs, " << std::fixed << std::setprecision(1)
    << (total < 3600 ? total / 60 : total / 3600) << (total < 3600 ? " min" : " h")
    << " of training in all.</p>\n<table><tr><th>model</th>";
  for (const auto& d : datasets) h << "<th>" << html_escape(d) << "</th>";
  h << "</tr>\n";
  for (const auto& m : models) {
    h << "<tr><th>" << html_escape(m) << "</th>";
    for (const auto& d : datasets) {
      const auto cell = detail::table_cell(cells, not_run, m, d);
      const CellSummary* it = cell.summary;
      if (!it) {
        if (cell.not_run)
          h << "<td title='" << html_escape(*cell.not_run) << "'>not run<br><small>"
            << (cell.failed() ? "failed" : "memory") << "</small></td>";
        else
          h << "<td>-</td>";
        continue;
      }
      h << "<td><a href='#" << m << "_" << d << "'>" << std::setprecision(2) << it->mean << " ± "
        << it->std << "</a><br><small>" << it->runs << " runs, " << std::setprecision(0)
        << it->seconds << " s</small></td>";
    }
    h << "</tr>\n";
  }
  h << "</table>\n<h2>Validation accuracy per split</h2>\n";
  const auto parsed = parse_curves(curves, curves_file);
  for (const auto& c : cells) {
    std::vector<std::pair<std::string, std::vector<double>>> series;
    int every = 1;
    for (const auto& r : runs) {
      if (r.model != c.model || r.dataset != c.dataset) continue;
      const auto it = parsed.find({r.model, r.dataset, r.split_seed});
      if (it == parsed.end()) continue;  // a run without its curve: none to draw
      const auto& [epochs, v] = it->second;
      if (epochs.size() >= 2) every = epochs[1] - epochs[0];
      series.emplace_back("split " + std::to_string(r.split_seed), v);
    }
    SvgPlotOptions plot;
    plot.xlabel = "validation check (every " + std::to_string(every) + " epochs)";
    plot.ylabel = "val accuracy";
    plot.ymax = 1;
    plot.x0 = 1;
    h << "<h3 id='" << c.model << "_" << c.dataset << "'>" << html_escape(c.model) << " on "
      << html_escape(c.dataset) << "</h3>\n"
      << svg_line_plot(series, plot) << "\n";
  }
  h << "</body></html>\n";
  return h.str();
}

TOPOS_INLINE RunsFolder::RunsFolder(std::filesystem::path out, std::vector<std::string> model_order)
    : out_(std::move(out)), model_order_(std::move(model_order)) {
  std::filesystem::create_directories(out_);
  curves_ = curves_header();
  if (const auto file = out_ / "curves.csv"; std::filesystem::exists(file)) {
    curves_ = data::read_text_file(file);
    parse_curves(curves_, file.string());  // a malformed row is named before anything runs
  }
  if (const auto file = out_ / "runs.csv"; std::filesystem::exists(file))
    runs_ = parse_runs(data::read_text_file(file), file.string());
  if (const auto file = out_ / "baselines.csv"; std::filesystem::exists(file)) {
    std::istringstream in(data::read_text_file(file));
    std::string line;
    for (int n = 1; std::getline(in, line); ++n) {
      if (n == 1 || line.empty()) continue;
      std::istringstream f(line);
      std::string d, seed, v;
      std::size_t a = 0, b = 0;
      try {
        if (!std::getline(f, d, ',') || !std::getline(f, seed, ',') || !std::getline(f, v))
          throw std::invalid_argument("fields");
        baselines_[{d, std::stoll(seed, &a)}] = std::stod(v, &b);
        if (a != seed.size() || b != v.size()) throw std::invalid_argument("trailing");
      } catch (const std::exception&) {
        throw data::DataError(file.string() + ":" + std::to_string(n) +
                              ": expected dataset,split_seed,majority_test_accuracy");
      }
    }
  }
}

TOPOS_INLINE void RunsFolder::add_baseline(const std::string& dataset, std::int64_t seed,
                                           double accuracy) {
  baselines_[{dataset, seed}] = accuracy;
  std::ostringstream o;
  o << "dataset,split_seed,majority_test_accuracy\n" << std::fixed << std::setprecision(6);
  for (const auto& [k, v] : baselines_) o << k.first << "," << k.second << "," << v << "\n";
  io::write_file_atomic((out_ / "baselines.csv").string(), o.str());
}

TOPOS_INLINE void RunsFolder::add(const RunResult& run, const std::vector<Check>& curve,
                                  const NotRun& not_run) {
  curves_ += format_curve(run, curve);
  io::write_file_atomic((out_ / "curves.csv").string(), curves_);
  runs_.push_back(run);
  io::write_file_atomic((out_ / "runs.csv").string(), format_runs(runs_));
  write_reports(not_run);
}

TOPOS_INLINE void RunsFolder::write_reports(const NotRun& not_run) const {
  io::write_file_atomic((out_ / "summary.csv").string(), format_summary(summarize(runs_)));
  io::write_file_atomic(
      (out_ / "index.html").string(),
      report_html(runs_, not_run, curves_, (out_ / "curves.csv").string(), model_order_));
  io::write_file_atomic((out_ / "table.md").string(), table_markdown(runs_, not_run, model_order_));
}

}  // namespace topos::models::topobench
