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
  friend bool operator<(const CochainKey& a, const CochainKey& b) { return std::tie(a.rank, a.state) < std::tie(b.rank, b.state); }
  friend bool operator==(const CochainKey& a, const CochainKey& b) { return a.rank == b.rank && a.state == b.state; }
  std::string str() const { return state.empty() ? "(" + std::to_string(rank) + ")" : "(" + std::to_string(rank) + ", \"" + state + "\")"; }
};

class Cochains {
 public:
  void set(int rank, const std::string& state, torch::Tensor x) { data_[{rank, state}] = std::move(x); }
  void set(int rank, torch::Tensor x) { set(rank, "", std::move(x)); }
  bool has(int rank, const std::string& state = "") const { return data_.count({rank, state}) > 0; }
  const torch::Tensor& at(int rank, const std::string& state = "") const {
    auto it = data_.find({rank, state});
    if (it == data_.end()) throw std::out_of_range("Cochains: no cochain " + CochainKey{rank, state}.str());
    return it->second;
  }
  const std::map<CochainKey, torch::Tensor>& items() const { return data_; }

 private:
  std::map<CochainKey, torch::Tensor> data_;
};

}  // namespace topos::nn
