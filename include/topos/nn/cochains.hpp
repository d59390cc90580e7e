// topos/nn/cochains.hpp
// Cochains: feature tensors per (rank, state). A rank may carry several states (HOPNet encodes
// each contact cell twice, once from each face's side: (3, "minus") and (3, "plus")).
#pragma once

#include <torch/torch.h>

#include <map>
#include <stdexcept>
#include <string>
#include <utility>

namespace topos::nn {

struct CochainKey {
  int rank = 0;
  std::string state;
  friend bool operator<(const CochainKey& a, const CochainKey& b) {
    return std::tie(a.rank, a.state) < std::tie(b.rank, b.state);
  }
  friend bool operator==(const CochainKey& a, const CochainKey& b) {
    return a.rank == b.rank && a.state == b.state;
  }
  std::string str() const {
    return state.empty() ? "(" + std::to_string(rank) + ")"
                         : "(" + std::to_string(rank) + ", \"" + state + "\")";
  }
};

/// A cochain may be held compactly: only the rows some message reads were computed, and
/// `rows(key)` maps every cell's row to its compact row (-1 where none was computed).
class Cochains {
 public:
  void set(int rank, const std::string& state, torch::Tensor x) {
    data_[{rank, state}] = std::move(x);
    rows_.erase({rank, state});
  }
  void set_compact(int rank, const std::string& state, torch::Tensor x, torch::Tensor row_of_cell) {
    data_[{rank, state}] = std::move(x);
    rows_[{rank, state}] = std::move(row_of_cell);
  }
  /// Undefined when the cochain holds every row.
  torch::Tensor rows(const CochainKey& k) const {
    auto it = rows_.find(k);
    return it == rows_.end() ? torch::Tensor() : it->second;
  }
  void set(int rank, torch::Tensor x) { set(rank, "", std::move(x)); }
  bool has(int rank, const std::string& state = "") const { return data_.count({rank, state}) > 0; }
  const torch::Tensor& at(int rank, const std::string& state = "") const {
    auto it = data_.find({rank, state});
    if (it == data_.end())
      throw std::out_of_range("Cochains: no cochain " + CochainKey{rank, state}.str());
    return it->second;
  }
  const std::map<CochainKey, torch::Tensor>& items() const { return data_; }

 private:
  std::map<CochainKey, torch::Tensor> data_;
  std::map<CochainKey, torch::Tensor> rows_;
};

}  // namespace topos::nn
