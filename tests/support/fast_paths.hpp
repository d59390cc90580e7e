// Checking OperatorNetwork's fast paths (nn::FastPaths) on a model: its outputs and gradients
// with every fast path off, against each fast path on alone and all on; and its step threads.
#pragma once

#include "support/torch_prelude.hpp"
#include "topos/nn/operator_schedule.hpp"

#include <algorithm>
#include <functional>
#include <string>
#include <vector>

namespace topos::test {

/// Every OperatorNetwork in `m`, `m` included.
inline std::vector<nn::OperatorNetworkImpl*> networks_in(torch::nn::Module& m) {
  std::vector<nn::OperatorNetworkImpl*> out;
  if (auto* n = dynamic_cast<nn::OperatorNetworkImpl*>(&m)) out.push_back(n);
  for (const auto& sub : m.modules(/*include_self=*/false))
    if (auto* n = dynamic_cast<nn::OperatorNetworkImpl*>(sub.get())) out.push_back(n);
  return out;
}

/// `run` (the outputs and gradients it returns, in one order every time) with every fast path of
/// `m`'s networks off, then with each on alone and with all on: each tensor within
/// atol + rtol · (its largest entry with all off) of all off. Returns the configurations whose
/// numbers differ from all off in some bit ("all" for all on), which the caller may report.
inline std::vector<std::string> check_fast_paths(
    torch::nn::Module& m, const std::function<std::vector<torch::Tensor>()>& run, double rtol,
    double atol) {
  const auto networks = networks_in(m);
  REQUIRE(!networks.empty());
  const auto with = [&](const nn::FastPaths& f) {
    for (auto* n : networks) n->fast_paths() = f;
    auto r = run();
    for (auto& t : r) t = t.defined() ? t.detach().clone() : t;
    return r;
  };
  const auto plain = with(nn::FastPaths::none());
  std::vector<std::string> changed;
  auto configurations = nn::FastPaths::names();
  configurations.push_back("all");
  for (const auto& name : configurations) {
    const auto f = name == "all" ? nn::FastPaths::all() : nn::FastPaths::none().set(name, true);
    const auto fast = with(f);
    REQUIRE(fast.size() == plain.size());
    bool same = true;
    for (std::size_t k = 0; k < fast.size(); ++k) {
      REQUIRE(fast[k].defined() == plain[k].defined());
      if (!plain[k].defined()) continue;
      REQUIRE(fast[k].sizes() == plain[k].sizes());
      if (plain[k].numel() == 0) continue;
      const double err = (fast[k] - plain[k]).abs().max().item<double>(),
                   scale = plain[k].abs().max().item<double>();
      INFO("fast path " << name << ", tensor " << k << ": max error " << err << ", largest "
                        << scale);
      CHECK(err <= atol + rtol * scale);
      same = same && torch::equal(fast[k], plain[k]);
    }
    if (!same) changed.push_back(name);
  }
  for (auto* n : networks) n->fast_paths() = nn::FastPaths::all();
  return changed;
}

/// `run` (its first `outputs` tensors the outputs, then gradients, as for check_fast_paths) with
/// `m` in eval mode, its networks on one step thread, then on 2 and 3
/// (OperatorNetworkImpl::step_threads): the outputs the same bit for bit, the gradients within
/// rtol · (the largest entry) + atol (autograd orders its sums by when each node was made, and
/// steps on other threads make theirs in another order). `m`'s training mode and its networks'
/// step threads are restored. Returns how many parallel groups and steps the 2- and 3-thread
/// runs split (OperatorNetworkImpl::split_groups, split_steps): 0 groups means the check
/// compared one thread with itself.
struct StepThreadSplits {
  std::int64_t groups = 0, steps = 0;
};
inline StepThreadSplits check_step_threads(torch::nn::Module& m,
                                           const std::function<std::vector<torch::Tensor>()>& run,
                                           std::size_t outputs, double rtol, double atol) {
  const auto networks = networks_in(m);
  REQUIRE(!networks.empty());
  const bool training = m.is_training();
  std::vector<int> before;
  for (auto* n : networks) before.push_back(n->step_threads());
  m.eval();
  const auto with = [&](int threads) {
    for (auto* n : networks) n->step_threads(threads);
    auto r = run();
    for (auto& t : r) t = t.defined() ? t.detach().clone() : t;
    return r;
  };
  const auto one = with(1);
  REQUIRE(outputs <= one.size());
  const auto split = [&] {
    StepThreadSplits n;
    for (auto* net : networks) n.groups += net->split_groups(), n.steps += net->split_steps();
    return n;
  };
  const auto split_before = split();
  for (int threads : {2, 3}) {
    const auto more = with(threads);
    REQUIRE(more.size() == one.size());
    for (std::size_t k = 0; k < one.size(); ++k) {
      REQUIRE(more[k].defined() == one[k].defined());
      if (!one[k].defined() || one[k].numel() == 0) continue;
      const double err = (more[k] - one[k]).abs().max().item<double>(),
                   scale = one[k].abs().max().item<double>();
      INFO(threads << " step threads, " << (k < outputs ? "output " : "gradient ") << k
                   << ": max difference " << err << ", largest " << scale);
      if (k < outputs)
        CHECK(torch::equal(more[k], one[k]));
      else
        CHECK(err <= atol + rtol * scale);
    }
  }
  for (std::size_t i = 0; i < networks.size(); ++i) networks[i]->step_threads(before[i]);
  m.train(training);
  const auto after = split();
  return {after.groups - split_before.groups, after.steps - split_before.steps};
}

/// The names, separated by spaces ("none" when empty), for a report.
inline std::string joined(const std::vector<std::string>& names) {
  std::string s;
  for (const auto& n : names) s += (s.empty() ? "" : " ") + n;
  return s.empty() ? "none" : s;
}

}  // namespace topos::test
