// topos/models/hopnet/normalization.hpp
// HOPNet's normalisation statistics (compute_normalization.py): per-column mean and std of
// x0..x4 and of the targets t0, t4, read from and written to JSON (keys `x0_mean` … `t4_std`,
// the layout of the shipped files), and computed from data with the equivariant shared scales:
// population moments over all cells of all timesteps, std < 1e-10 replaced by 1, then shared
// maxima per block (x0[0:8], x0[8:16], x1, x2, t0, t4, x3[0:4], x3's three vertex blocks shared
// between the two faces, x4[0:8]) and the type columns x4[8:10] forced to mean 0.5, std 0.5.
// The ablations' files differ (the ablations' normalisation files): x0 has 21 columns with virtual
// object nodes (the last 5 are x4's object columns, type forced to 0.5/0.5) and 8 without the
// centre-mass distances, and without object cells x4/t4 are absent (JSON null).
// No LibTorch; the float32 application lives with the model.
#pragma once

#include "topos/io/atomic_file.hpp"
#include "topos/data/kubric.hpp"
#include "topos/models/namespace_aliases.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <string>
#include <vector>

namespace topos::models::hopnet {

struct NormalizationStats {
  /// key ("x0".."x4", "t0", "t4") -> per-column values
  std::map<std::string, std::vector<double>> mean, std;

  /// The standard layout (x0 16 columns, object statistics present).
  static const std::vector<std::pair<std::string, std::size_t>>& layout() {
    static const std::vector<std::pair<std::string, std::size_t>> l = layout_for(16, true);
    return l;
  }
  /// The layout of a file with `x0_width` node columns, with or without x4/t4.
  static std::vector<std::pair<std::string, std::size_t>> layout_for(std::size_t x0_width,
                                                                     bool objects) {
    std::vector<std::pair<std::string, std::size_t>> l{
        {"x0", x0_width}, {"x1", 8}, {"x2", 3}, {"x3", 28}};
    if (objects) l.push_back({"x4", 13});
    l.push_back({"t0", 3});
    if (objects) l.push_back({"t4", 3});
    return l;
  }
  /// This file's layout (read off x0's width and whether x4 is present).
  std::vector<std::pair<std::string, std::size_t>> keys() const {
    auto it = mean.find("x0");
    return layout_for(it == mean.end() ? 16 : it->second.size(), mean.count("x4") > 0);
  }
  bool has_objects() const { return mean.count("x4") > 0; }
  std::size_t x0_width() const { return mean.count("x0") ? mean.at("x0").size() : 0; }

  /// Throws DataError when a key is missing, has the wrong length, or a std is not positive.
  /// x0 may have 8, 13, 16 or 21 columns; x4 and t4 are both present or both absent.
  void validate(const std::string& source) const {
    const std::size_t w = x0_width();
    if (mean.count("x0") && w != 8 && w != 13 && w != 16 && w != 21)
      throw data::DataError(
          source + ": 'x0_mean' has " + std::to_string(w) +
          " entries, expected 16 (HOPNet), 21 (no object cells) or 8 (no centre-mass distance)");
    if (mean.count("x4") != mean.count("t4"))
      throw data::DataError(source +
                            ": 'x4' and 't4' statistics must both be present or both be null");
    for (const auto& [k, n] : keys()) {
      for (const auto* m : {&mean, &std}) {
        const std::string name = k + (m == &mean ? "_mean" : "_std");
        auto it = m->find(k);
        if (it == m->end()) throw data::DataError(source + ": missing statistics '" + name + "'");
        if (it->second.size() != n)
          throw data::DataError(source + ": '" + name + "' has " +
                                std::to_string(it->second.size()) + " entries, expected " +
                                std::to_string(n));
        for (double v : it->second)
          if (!std::isfinite(v) || (m == &std && !(v > 0)))
            throw data::DataError(source + ": '" + name +
                                  "' holds a non-finite or non-positive value");
      }
    }
  }
};

inline NormalizationStats parse_stats_json(const std::string& text, const std::string& source) {
  const nlohmann::json j = data::parse_json(text, source);
  if (!j.is_object()) throw data::DataError(source + ": expected an object of statistics");
  NormalizationStats s;
  for (const auto& [k, n] : NormalizationStats::layout()) {
    for (const char* suffix : {"_mean", "_std"}) {
      const std::string name = k + suffix;
      if (!j.contains(name)) throw data::DataError(source + ": missing statistics '" + name + "'");
      if ((k == "x4" || k == "t4") && j[name].is_null()) continue;  // no object cells
      try {
        (suffix[1] == 'm' ? s.mean : s.std)[k] = j[name].get<std::vector<double>>();
      } catch (const nlohmann::json::exception&) {
        throw data::DataError(source + ": '" + name + "' is not an array of numbers");
      }
    }
  }
  if (s.mean.count("x4") != s.std.count("x4") || s.mean.count("t4") != s.std.count("t4"))
    throw data::DataError(
        source +
        ": object statistics are null for the mean but not the std, or the other way round");
  s.validate(source);
  return s;
}

inline NormalizationStats read_stats_json(const std::string& path) {
  return parse_stats_json(data::read_text_file(path), path);
}

/// Writes the statistics (shortest round-trip doubles) to a temporary file, then renames it.
inline void write_stats_json(const NormalizationStats& s, const std::string& path) {
  s.validate(path);
  nlohmann::json j;
  for (const auto& [k, n] : NormalizationStats::layout()) {
    const bool present = s.mean.count(k) > 0;
    j[k + "_mean"] = present ? nlohmann::json(s.mean.at(k)) : nlohmann::json();
    j[k + "_std"] = present ? nlohmann::json(s.std.at(k)) : nlohmann::json();
  }
  try {
    io::write_file_atomic(path, j.dump(1) + "\n");
  } catch (const std::runtime_error& e) {
    throw data::DataError(e.what());
  }
}

/// Accumulates population moments per column (compensated by a per-column shift, the first
/// row seen, so small variances around large means stay accurate).
class StatsAccumulator {
 public:
  template <class Matrix>
  void add(const std::string& key, const Matrix& rows) {
    auto& a = acc_[key];
    if (rows.rows() == 0) return;
    if (a.shift.empty()) {
      a.shift.resize(static_cast<std::size_t>(rows.cols()));
      for (Eigen::Index c = 0; c < rows.cols(); ++c)
        a.shift[static_cast<std::size_t>(c)] = rows(0, c);
      a.sum.assign(a.shift.size(), 0.0L);
      a.sumsq.assign(a.shift.size(), 0.0L);
    }
    if (static_cast<std::size_t>(rows.cols()) != a.shift.size())
      throw std::invalid_argument("StatsAccumulator: '" + key + "' changed width");
    for (Eigen::Index r = 0; r < rows.rows(); ++r)
      for (Eigen::Index c = 0; c < rows.cols(); ++c) {
        const long double d =
            static_cast<long double>(rows(r, c)) - a.shift[static_cast<std::size_t>(c)];
        a.sum[static_cast<std::size_t>(c)] += d;
        a.sumsq[static_cast<std::size_t>(c)] += d * d;
      }
    a.count += rows.rows();
  }
  void merge(const StatsAccumulator& other) {
    for (const auto& [k, b] : other.acc_) {
      auto& a = acc_[k];
      if (b.count == 0) continue;
      if (a.count == 0) {
        a = b;
        continue;
      }
      for (std::size_t c = 0; c < a.shift.size(); ++c) {
        // Re-centre b on a's shift: d' = d + (b.shift - a.shift).
        const long double s = static_cast<long double>(b.shift[c]) - a.shift[c];
        a.sumsq[c] += b.sumsq[c] + 2 * s * b.sum[c] + static_cast<long double>(b.count) * s * s;
        a.sum[c] += b.sum[c] + static_cast<long double>(b.count) * s;
      }
      a.count += b.count;
    }
  }
  std::int64_t count(const std::string& key) const {
    auto it = acc_.find(key);
    return it == acc_.end() ? 0 : it->second.count;
  }

  /// Mean and std per column with the reference's shared scales. The layout follows what was
  /// added: x0's width, and x4/t4 only if object rows were added (none without object cells).
  NormalizationStats finalize() const {
    NormalizationStats s;
    const auto x0 = acc_.find("x0");
    const std::size_t w =
        x0 == acc_.end() || x0->second.shift.empty() ? 16 : x0->second.shift.size();
    for (const auto& [k, n] :
         NormalizationStats::layout_for(w, acc_.count("x4") > 0 || x0 == acc_.end())) {
      auto it = acc_.find(k);
      std::vector<double> mean(n, 0.0), sd(n, 1.0);
      if (it != acc_.end() && it->second.count > 0) {
        const auto& a = it->second;
        const long double cnt = static_cast<long double>(a.count);
        for (std::size_t c = 0; c < n; ++c) {
          const long double m = a.sum[c] / cnt;
          mean[c] = static_cast<double>(a.shift[c] + m);
          const double var = static_cast<double>(std::max(0.0L, a.sumsq[c] / cnt - m * m));
          sd[c] = std::sqrt(var);
          if (sd[c] < 1e-10) sd[c] = 1.0;
        }
      }
      const auto share = [&](std::vector<std::pair<std::size_t, std::size_t>> blocks) {
        double mx = 0;
        for (auto [b, e] : blocks)
          for (std::size_t c = b; c < e; ++c) mx = std::max(mx, sd[c]);
        for (auto [b, e] : blocks)
          for (std::size_t c = b; c < e; ++c) sd[c] = mx;
      };
      if (k == "x0") {
        share({{0, 8}});
        if (n >= 16) share({{8, 16}});
        if (n == 13 || n == 21)
          mean[n - 5] = mean[n - 4] = 0.5, sd[n - 5] = sd[n - 4] = 0.5;  // object type
      }
      if (k == "x1" || k == "x2" || k == "t0" || k == "t4") share({{0, n}});
      if (k == "x3")
        share({{0, 4}}), share({{4, 8}, {16, 20}}), share({{8, 12}, {20, 24}}),
            share({{12, 16}, {24, 28}});
      if (k == "x4") {
        share({{0, 8}});
        mean[8] = mean[9] = 0.5;
        sd[8] = sd[9] = 0.5;
      }
      s.mean[k] = mean;
      s.std[k] = sd;
    }
    return s;
  }

 private:
  struct Acc {
    std::vector<double> shift;
    std::vector<long double> sum, sumsq;
    std::int64_t count = 0;
  };
  std::map<std::string, Acc> acc_;
};

}  // namespace topos::models::hopnet
