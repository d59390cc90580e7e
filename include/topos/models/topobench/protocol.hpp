// topos/models/topobench/protocol.hpp
// TopoBench's protocol as data (std only): the hyperparameters of every (model, dataset) pair
// parsed from the one-run-per-line file `reproduce-hparams.txt` (TopoBench's
// scripts/reproduce.sh, see ../shared/datasets/topobench/), the table's dataset names, what a
// table model declares (ModelSpec; table_models.hpp registers them), its random splits, runs.csv,
// the runner's resumable record of finished runs, and the summary (mean and std over splits).
#pragma once

#include "topos/data/error.hpp"                // DataError, read_text_file
#include "topos/models/topobench/lifting.hpp"  // Domain
#include "topos/models/topobench/split.hpp"
#include "topos/io/atomic_file.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <iomanip>
#include <map>
#include <numeric>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace topos::models::topobench {

/// What a backbone works on, the part of a model's spec the pipeline needs (a user's backbone
/// declares its own; the table's come from ModelSpec): the domain the data is lifted to, the
/// ranks the encoder reads (x_r at the hidden width), how many ranks the backbone returns and the
/// wrapper and readout see (x_0 .. x_{cell_dimensions-1}), and the operators (lifting.hpp's
/// names) it and the readout read, which are all the lifting builds.
struct RankLayout {
  Domain domain = Domain::graph;
  std::vector<int> encoded_ranks = {0};
  int cell_dimensions = 1;
  std::set<std::string> operators;
};

/// What the pipeline needs of a table model, besides its backbone: the table's name, TopoBench's
/// config (domain/name), the domain it lifts to, the ranks its encoder reads, how many ranks its
/// wrapper and readout see (TopoBench's num_cell_dimensions: 3 for cells and simplices, see
/// docs/topobench.md), and the operators (topobench/lifting.hpp's names) its backbone and
/// readout use. The table's rows are table_models.hpp's (`model_specs()`, `model_spec(name)`),
/// each registered there once with its backbone.
struct ModelSpec {
  const char* name;
  const char* config;
  Domain domain;
  std::vector<int> encoded_ranks;
  int cell_dimensions;
  std::set<std::string> operators;
};
/// TopoTune's cell routes (TopoBench's configs/model/cell/topotune.yaml, `neighborhoods`).
inline const std::vector<std::string>& topotune_cell_neighborhoods() {
  static const std::vector<std::string> n = {"up_adjacency-1", "up_incidence-0", "down_incidence-2",
                                             "2-up_adjacency-0"};
  return n;
}

/// The table's datasets and the names TopoBench's configs give them.
struct DatasetName {
  const char* name;
  const char* config;
  bool node_level;
};
inline const std::vector<DatasetName>& table_datasets() {
  static const std::vector<DatasetName> d = {{"MUTAG", "MUTAG", false},
                                             {"PROTEINS", "PROTEINS", false},
                                             {"NCI1", "NCI1", false},
                                             {"NCI109", "NCI109", false},
                                             {"IMDB-BINARY", "IMDB-BINARY", false},
                                             {"IMDB-MULTI", "IMDB-MULTI", false},
                                             {"REDDIT-BINARY", "REDDIT-BINARY", false},
                                             {"Cora", "cocitation_cora", true},
                                             {"Citeseer", "cocitation_citeseer", true}};
  return d;
}

template <class T>
const T& find_name(const std::vector<T>& list, const std::string& name, const char* what) {
  for (const auto& x : list)
    if (name == x.name) return x;
  std::string known;
  for (const auto& x : list) known += std::string(known.empty() ? "" : ", ") + x.name;
  throw std::invalid_argument(std::string("unknown ") + what + " '" + name + "' (known: " + known +
                              ")");
}

/// One (model, dataset) line of reproduce-hparams.txt.
struct RunConfig {
  std::string model_config, dataset_config;  ///< e.g. "cell/cwn", "MUTAG"
  double lr = 0, dropout = 0;
  std::int64_t hidden = 0, layers = 0, batch_size = 0;
  std::string readout;  ///< PropagateSignalDown, NoReadOut, or empty (graph models)
  std::vector<std::int64_t> data_seeds;
  int max_epochs = 0, min_epochs = 0, val_every = 1, patience = 0;
  bool signed_incidence = false;  ///< transforms.graph2simplicial_lifting.signed
  int max_cell_length = 0;        ///< transforms.graph2cell_lifting.max_cell_length
  std::string source;             ///< file:line, for messages
};

inline std::vector<RunConfig> parse_hparams(const std::string& text, const std::string& file) {
  std::vector<RunConfig> out;
  std::istringstream in(text);
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    if (line.empty() || line[0] == '#') continue;
    const std::string where = file + ":" + std::to_string(n);
    std::istringstream words(line);
    RunConfig c;
    c.source = where;
    if (!(words >> c.model_config >> c.dataset_config))
      throw topos::data::DataError(where + ": expected 'domain/model DATASET key=value...'");
    const auto number = [&](const std::string& key, const std::string& v) {
      std::size_t used = 0;
      double x = 0;
      try {
        x = std::stod(v, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used != v.size() || !std::isfinite(x))
        throw topos::data::DataError(where + ": " + key + "=" + v + " is not a number");
      return x;
    };
    const auto integer = [&](const std::string& key, const std::string& v) {
      const double x = number(key, v);
      if (x != std::floor(x) || std::abs(x) > 1e15)
        throw topos::data::DataError(where + ": " + key + "=" + v + " is not an integer");
      return static_cast<std::int64_t>(x);
    };
    std::string kv;
    while (words >> kv) {
      const auto eq = kv.find('=');
      if (eq == std::string::npos || eq == 0)
        throw topos::data::DataError(where + ": '" + kv + "' is not key=value");
      const std::string key = kv.substr(0, eq), v = kv.substr(eq + 1);
      if (key == "lr")
        c.lr = number(key, v);
      else if (key == "hid")
        c.hidden = integer(key, v);
      else if (key == "L")
        c.layers = integer(key, v);
      else if (key == "bs")
        c.batch_size = integer(key, v);
      else if (key == "dropout")
        c.dropout = number(key, v);
      else if (key == "readout")
        c.readout = v;
      else if (key == "trainer.max_epochs")
        c.max_epochs = static_cast<int>(integer(key, v));
      else if (key == "trainer.min_epochs")
        c.min_epochs = static_cast<int>(integer(key, v));
      else if (key == "trainer.check_val_every_n_epoch")
        c.val_every = static_cast<int>(integer(key, v));
      else if (key == "callbacks.early_stopping.patience")
        c.patience = static_cast<int>(integer(key, v));
      else if (key == "transforms.graph2simplicial_lifting.signed") {
        if (v != "True" && v != "False")
          throw topos::data::DataError(where + ": " + key + "=" + v + " is not True or False");
        c.signed_incidence = v == "True";
      } else if (key == "transforms.graph2cell_lifting.max_cell_length")
        c.max_cell_length = static_cast<int>(integer(key, v));
      else if (key == "dataset.split_params.data_seed") {
        std::istringstream seeds(v);
        std::string s;
        while (std::getline(seeds, s, ',')) c.data_seeds.push_back(integer(key, s));
      }
      // Other keys (ZINC's regression settings and its model seeds `seed`) concern no table
      // cell; they are kept out.
    }
    if (c.lr <= 0 || c.hidden <= 0 || c.layers <= 0 || c.batch_size <= 0 || c.max_epochs <= 0 ||
        c.val_every <= 0 || c.patience <= 0)
      throw topos::data::DataError(where +
                                   ": lr, hid, L, bs, trainer.max_epochs, "
                                   "check_val_every_n_epoch and patience must all be "
                                   "given and positive");
    out.push_back(std::move(c));
  }
  return out;
}

inline std::vector<RunConfig> read_hparams(const std::filesystem::path& path) {
  return parse_hparams(topos::data::read_text_file(path), path.string());
}

inline RankLayout rank_layout(const ModelSpec& m) {
  return {m.domain, m.encoded_ranks, m.cell_dimensions, m.operators};
}
inline const DatasetName& dataset_name(const std::string& name) {
  return find_name(table_datasets(), name, "TopoBench dataset");
}

/// A model whose config has no line in reproduce-hparams.txt (TopoBench's reproduce script has
/// none for TopoTune) runs with another model's line per dataset (the lifting, lr, batch size,
/// encoder dropout, epochs, patience, seeds) and what its own config fixes.
struct BorrowedProtocol {
  const char* config;  ///< the model's config
  const char* from;    ///< the config whose lines it takes
  std::int64_t hidden, layers;
  const char* readout;
};
inline const std::vector<BorrowedProtocol>& borrowed_protocols() {
  // topotune.yaml: feature_encoder.out_channels 32, backbone.layers 2, PropagateSignalDown.
  static const std::vector<BorrowedProtocol> b = {
      {"cell/topotune", "cell/cwn", 32, 2, "PropagateSignalDown"}};
  return b;
}

inline RunConfig find_config(const std::vector<RunConfig>& all, const ModelSpec& model,
                             const DatasetName& dataset) {
  for (const auto& c : all)
    if (c.model_config == model.config && c.dataset_config == dataset.config) return c;
  for (const auto& b : borrowed_protocols())
    if (model.config == std::string(b.config))
      for (const auto& c : all)
        if (c.model_config == b.from && c.dataset_config == dataset.config) {
          RunConfig own = c;
          own.model_config = b.config;
          own.hidden = b.hidden, own.layers = b.layers, own.readout = b.readout;
          own.source += std::string(" (") + b.from + "'s line; " + b.config +
                        ": hid=" + std::to_string(b.hidden) + " L=" + std::to_string(b.layers) +
                        " readout=" + b.readout + ")";
          return own;
        }
  throw std::invalid_argument(std::string("no hyperparameters for ") + model.name + " (" +
                              model.config + ") on " + dataset.name + " (" + dataset.config + ")");
}

/// One finished run: a row of runs.csv.
struct RunResult {
  std::string model, dataset;
  std::int64_t split_seed = 0;
  double test_accuracy = 0;  ///< in [0, 1]
  int best_epoch = 0, epochs = 0;
  double seconds = 0;
};

/// One validation check of a run: its epoch, the mean training loss and the validation accuracy.
struct Check {
  int epoch;
  double loss, val_accuracy;
};

inline const char* runs_header() {
  return "model,dataset,split_seed,test_accuracy,best_epoch,epochs,seconds";
}

/// runs.csv as written by write_runs; a malformed row is an error naming the file and line.
inline std::vector<RunResult> parse_runs(const std::string& text, const std::string& file) {
  std::vector<RunResult> out;
  std::istringstream in(text);
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    if (n == 1) {
      if (line != runs_header())
        throw topos::data::DataError(file + ":1: expected the header '" +
                                     std::string(runs_header()) + "'");
      continue;
    }
    std::vector<std::string> f;
    std::istringstream cells(line);
    std::string cell;
    while (std::getline(cells, cell, ',')) f.push_back(cell);
    const std::string where = file + ":" + std::to_string(n);
    if (f.size() != 7) throw topos::data::DataError(where + ": expected 7 fields");
    RunResult r;
    r.model = f[0], r.dataset = f[1];
    try {
      std::size_t a = 0, b = 0, c = 0, d = 0, e = 0;
      r.split_seed = std::stoll(f[2], &a);
      r.test_accuracy = std::stod(f[3], &b);
      r.best_epoch = std::stoi(f[4], &c);
      r.epochs = std::stoi(f[5], &d);
      r.seconds = std::stod(f[6], &e);
      if (a != f[2].size() || b != f[3].size() || c != f[4].size() || d != f[5].size() ||
          e != f[6].size())
        throw std::invalid_argument("trailing characters");
    } catch (const std::exception&) {
      throw topos::data::DataError(where + ": a field is not a number");
    }
    if (!(r.test_accuracy >= 0 && r.test_accuracy <= 1))
      throw topos::data::DataError(where + ": test_accuracy outside [0, 1]");
    out.push_back(r);
  }
  return out;
}

inline std::string format_runs(const std::vector<RunResult>& runs) {
  std::ostringstream o;
  o << runs_header() << "\n";
  o.precision(17);
  for (const auto& r : runs) {
    o << r.model << "," << r.dataset << "," << r.split_seed << ",";
    o.precision(6);
    o << std::fixed << r.test_accuracy << "," << r.best_epoch << "," << r.epochs << ","
      << std::setprecision(2) << r.seconds << "\n";
    o << std::defaultfloat;
  }
  return o.str();
}

/// Mean and standard deviation (numpy's default, ddof 0) of a cell's test accuracies, in percent.
struct CellSummary {
  std::string model, dataset;
  double mean = 0, std = 0, seconds = 0;
  int runs = 0;
};
inline std::vector<CellSummary> summarize(const std::vector<RunResult>& runs) {
  std::vector<CellSummary> out;
  for (const auto& r : runs) {
    auto it = std::find_if(out.begin(), out.end(), [&](const CellSummary& c) {
      return c.model == r.model && c.dataset == r.dataset;
    });
    if (it == out.end()) out.push_back({r.model, r.dataset}), it = out.end() - 1;
    it->mean += 100 * r.test_accuracy, it->seconds += r.seconds, ++it->runs;
  }
  for (auto& c : out) {
    c.mean /= c.runs;
    double ss = 0;
    for (const auto& r : runs)
      if (r.model == c.model && r.dataset == c.dataset)
        ss += (100 * r.test_accuracy - c.mean) * (100 * r.test_accuracy - c.mean);
    c.std = std::sqrt(ss / c.runs);
  }
  return out;
}

inline std::string format_summary(const std::vector<CellSummary>& cells) {
  std::ostringstream o;
  o << "model,dataset,mean,std,runs,seconds\n" << std::fixed;
  for (const auto& c : cells)
    o << c.model << "," << c.dataset << "," << std::setprecision(2) << c.mean << "," << c.std << ","
      << c.runs << "," << std::setprecision(1) << c.seconds << "\n";
  return o.str();
}

}  // namespace topos::models::topobench
