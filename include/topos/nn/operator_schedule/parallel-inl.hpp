// topos/nn/operator_schedule/parallel-inl.hpp
// How a forward shares its work with helper threads (OperatorNetworkImpl::step_threads): a
// parallel group's steps in units that share no cached prefix, a step's terms in jobs, each run
// on the calling thread and helpers with the caller's thread state. Part of the interpreter
// (interpreter-inl.hpp); compiled into topos::nn, or inline with TOPOS_HEADER_ONLY.
#pragma once

#include "topos/nn/helper_thread.hpp"
#include "topos/nn/kernels/packed_weights.hpp"
#include "topos/nn/operator_schedule/network.hpp"

#include <ATen/Parallel.h>
#include <ATen/ThreadLocalState.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <exception>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <numeric>
#include <set>
#include <string>
#include <vector>

#if defined(__x86_64__) || defined(__i386__)
#include <xmmintrin.h>  // _mm_getcsr: a helper flushes denormals as its caller does
#endif

namespace topos::nn::detail {

/// A group's live steps in units, each run on one thread: steps that may share a cached term
/// prefix (the same prefix key, or filter taps over the same source cochain) stay in one unit,
/// transitively. Units in the order of their first step, steps in order within a unit.
inline std::vector<std::vector<std::size_t>> step_units(const std::vector<PlannedStep>& steps,
                                                        bool live_only) {
  std::vector<std::size_t> parent(steps.size());  // union-find over the steps
  std::iota(parent.begin(), parent.end(), std::size_t{0});
  const auto root = [&](std::size_t i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  std::map<std::string, std::size_t> first_with;  // a sharing key's first step
  for (std::size_t i = 0; i < steps.size(); ++i) {
    const auto& p = steps[i];
    if (live_only && !p.live) continue;
    for (const auto& t : p.terms) {
      std::vector<std::string> keys;
      if (!t.prefix_key.empty()) keys.push_back("prefix " + t.prefix_key);
      if (p.route == StepRoute::filter || !p.compact_readers.empty())
        keys.push_back("source " + t.term->source.str());
      for (const auto& k : keys) {
        const auto [it, fresh] = first_with.emplace(k, i);
        if (!fresh) {
          const auto a = root(it->second), b = root(i);
          parent[std::max(a, b)] = std::min(a, b);
        }
      }
    }
  }
  std::vector<std::vector<std::size_t>> units;
  std::map<std::size_t, std::size_t> unit_of_root;
  for (std::size_t i = 0; i < steps.size(); ++i) {
    if (live_only && !steps[i].live) continue;
    const auto [it, fresh] = unit_of_root.emplace(root(i), units.size());
    if (fresh) units.emplace_back();
    units[it->second].push_back(i);
  }
  return units;
}

/// The networks whose helper threads are in use: a second forward of one of them at the same
/// time (another thread's, or an operation's inside a step) runs its groups on one thread.
inline std::mutex& busy_networks_mutex() {
  static std::mutex m;
  return m;
}
inline std::set<const void*>& busy_networks() {
  static std::set<const void*> s;
  return s;
}

// How long a helper polls for the next job before it sleeps: a rollout's forward and the work
// between two forwards (a millisecond) pass without a sleep, whose wake-up took 90 µs on average
// on a 2-vCPU VM (a group's steps take 100-250 µs there).
inline constexpr std::chrono::microseconds kHelperSpin{2000};

/// `take` on the calling thread and on the first `n` of `helpers` (made where missing) at once,
/// with `shared` true meanwhile; returns once every one has finished, whatever throws. A helper
/// runs it with what a thread does not inherit: LibTorch's thread-local state (grad mode and the
/// like), the OpenMP team size (oneDNN's products read it), denormal flushing (MXCSR), the
/// packed bfloat16 weights' scope. `take` keeps its own errors.
inline void run_with_helpers(std::vector<std::unique_ptr<HelperThread>>& helpers, std::size_t n,
                             bool& shared, const std::function<void()>& take) {
  const at::ThreadLocalState state;
  const auto packed_scope = packed_weights_scope();
  const int intra_op = at::get_num_threads();
#if defined(__x86_64__) || defined(__i386__)
  const unsigned csr = _mm_getcsr();
#endif
  for (std::size_t k = 0; k < n; ++k)  // all made before any job refers to this frame
    if (!helpers[k]) helpers[k] = std::make_unique<HelperThread>(kHelperSpin);
  // Every job posted is waited for, whatever throws, before this frame goes.
  struct Join {
    std::vector<std::unique_ptr<HelperThread>>& helpers;
    bool& shared;
    std::size_t posted = 0;
    ~Join() {
      for (; posted > 0; --posted) try {
          helpers[posted - 1]->wait();
        } catch (...) {  // `take` keeps its errors: nothing to lose here
        }
      shared = false;
    }
  } join{helpers, shared};
  shared = true;
  for (; join.posted < n; ++join.posted) {
    helpers[join.posted]->post([&] {
      at::ThreadLocalStateGuard guard(state);
      if (at::get_num_threads() != intra_op) at::set_num_threads(intra_op);
      adopt_packed_weights_scope(packed_scope);
#if defined(__x86_64__) || defined(__i386__)
      const unsigned own = _mm_getcsr();
      _mm_setcsr(csr);
#endif
      take();
#if defined(__x86_64__) || defined(__i386__)
      _mm_setcsr(own);
#endif
    });
  }
  take();
}

// A term's row-wise prefix worth a helper's time: about a million multiply-adds at 128 channels.
inline constexpr std::int64_t kTermRows = 32;

// A term that run_step may evaluate on a helper: a row-wise prefix, then an aggregation over a
// batch's neighbourhood (evaluate_term's).
inline bool may_run_ahead(const PlannedTerm& t) {
  return !t.neighborhood.empty() && t.row_wise_prefix > 0;
}

/// Whether a live step of the group has two terms that may run ahead (term_jobs may split it).
inline bool may_split_terms(const std::vector<PlannedStep>& steps, bool live_only) {
  for (const auto& p : steps) {
    if (live_only && !p.live) continue;
    int n = 0;
    for (const auto& t : p.terms) n += may_run_ahead(t) ? 1 : 0;
    if (n >= 2) return true;
  }
  return false;
}

/// The jobs a step's terms may be evaluated in at once (run_step, step_threads): the terms that
/// aggregate over a batch's neighbourhood after a row-wise prefix (evaluate_term's), those that
/// may share a cached prefix in one job, the jobs by their source rows, most first. Empty where
/// fewer than two jobs read kTermRows rows or more.
inline std::vector<std::vector<std::size_t>> term_jobs(const PlannedStep& p, const Cochains& h) {
  std::vector<std::vector<std::size_t>> jobs;
  std::vector<std::int64_t> rows;
  std::map<std::string, std::size_t> job_of_key;
  for (std::size_t k = 0; k < p.terms.size(); ++k) {
    const auto& t = p.terms[k];
    const auto& source = t.term->source;
    if (!may_run_ahead(t) || !h.has(source.rank, source.state)) continue;  // left to the step
    auto j = jobs.size();
    if (!t.prefix_key.empty()) j = job_of_key.emplace(t.prefix_key, j).first->second;
    if (j == jobs.size()) jobs.emplace_back(), rows.push_back(0);
    jobs[j].push_back(k);
    rows[j] += h.at(source.rank, source.state).size(0);
  }
  std::vector<std::size_t> order(jobs.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return rows[a] > rows[b]; });
  if (order.size() < 2 || rows[order[1]] < kTermRows) return {};
  std::vector<std::vector<std::size_t>> sorted;
  for (auto j : order) sorted.push_back(std::move(jobs[j]));
  return sorted;
}

/// `evaluate(term, cache)` for the terms of `jobs` on the calling thread and up to `n` helpers,
/// each job with the entries of `cache` its terms may read (the prefixes it adds are added to
/// `cache` after), into `ahead` by term: each value or the error it threw, for the step to take
/// in its order.
template <class Value, class Evaluate>
void evaluate_at_once(std::vector<std::unique_ptr<HelperThread>>& helpers, std::size_t n,
                      bool& shared, const std::vector<std::vector<std::size_t>>& jobs,
                      const std::vector<PlannedTerm>& terms,
                      std::map<std::string, torch::Tensor>& cache,
                      std::map<const PlannedTerm*, Value>& ahead, const Evaluate& evaluate) {
  std::vector<Value> values(terms.size());
  std::vector<char> done(terms.size(), 0);  // not vector<bool>: threads write their own terms
  std::vector<std::map<std::string, torch::Tensor>> caches(jobs.size());
  for (std::size_t j = 0; j < jobs.size(); ++j)
    for (auto k : jobs[j]) {
      const auto it = cache.find(terms[k].prefix_key);
      if (it != cache.end()) caches[j].insert(*it);
    }
  std::atomic<std::size_t> next{0};
  run_with_helpers(helpers, std::min(n, jobs.size() - 1), shared, [&] {
    for (std::size_t j; (j = next.fetch_add(1)) < jobs.size();)
      for (auto k : jobs[j]) {
        done[k] = 1;
        try {
          values[k] = evaluate(terms[k], caches[j]);
        } catch (...) {
          values[k].error = std::current_exception();
          break;  // the job's later terms may read its cache: left to the step
        }
      }
  });
  for (std::size_t k = 0; k < terms.size(); ++k)
    if (done[k]) ahead.emplace(&terms[k], std::move(values[k]));
  for (auto& c : caches) cache.insert(c.begin(), c.end());
}

}  // namespace topos::nn::detail
