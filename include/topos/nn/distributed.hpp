// topos/nn/distributed.hpp
// Data-parallel training on LibTorch's own distributed engine (c10d), not a home-made protocol:
// rendezvous from the environment torchrun sets (RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR,
// MASTER_PORT) through c10d's TCPStore, or through a c10d FileStore when TOPOS_RENDEZVOUS_FILE
// names one (the local launcher's choice: nothing listens on a network port); a Gloo process
// group on CPU, NCCL when LibTorch has CUDA and the model lives on a GPU. On top: bucketed
// gradient averaging, broadcasts of parameters and bytes, and deterministic epoch sharding.
// Every collective has a timeout, so a dead or hung worker makes the others fail with a
// DistributedError naming it instead of hanging. A world of one process needs none of this:
// Distributed then runs every operation locally, so one code path serves both.
#pragma once

#include <torch/torch.h>

#if defined(TOPOS_WITH_C10D_GLOO) || defined(TOPOS_WITH_C10D_NCCL)
#include <torch/csrc/distributed/c10d/FileStore.hpp>
#include <torch/csrc/distributed/c10d/PrefixStore.hpp>
#include <torch/csrc/distributed/c10d/TCPStore.hpp>
#endif
#ifdef TOPOS_WITH_C10D_GLOO
#include <torch/csrc/distributed/c10d/ProcessGroupGloo.hpp>
#endif
#ifdef TOPOS_WITH_C10D_NCCL
#include <torch/csrc/distributed/c10d/ProcessGroupNCCL.hpp>
#endif

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <mutex>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::nn {

/// A collective or rendezvous failed: a worker died, hung past the timeout, or never came.
class DistributedError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Which c10d backends this build of topos can use.
inline bool gloo_available() {
#ifdef TOPOS_WITH_C10D_GLOO
  return true;
#else
  return false;
#endif
}
inline bool nccl_available() {
#ifdef TOPOS_WITH_C10D_NCCL
  return true;
#else
  return false;
#endif
}

/// Where this process sits in the job, as torchrun describes it in the environment.
struct DistributedEnv {
  int rank = 0, world_size = 1, local_rank = 0, local_world_size = 1;
  std::string master_addr = "127.0.0.1";
  int master_port = 29500;
  std::string rendezvous_file;  ///< TOPOS_RENDEZVOUS_FILE: a c10d FileStore instead of the TCPStore

  /// Reads RANK, WORLD_SIZE, LOCAL_RANK, LOCAL_WORLD_SIZE, MASTER_ADDR, MASTER_PORT and
  /// TOPOS_RENDEZVOUS_FILE; without WORLD_SIZE the job is this one process.
  static DistributedEnv from_environment() {
    DistributedEnv e;
    const auto get = [](const char* name) -> std::string {
      const char* v = std::getenv(name);
      return v ? std::string(v) : std::string();
    };
    const auto integer = [&](const char* name, int fallback, int min) {
      const std::string s = get(name);
      if (s.empty()) return fallback;
      std::size_t used = 0;
      int v = 0;
      try {
        v = std::stoi(s, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used != s.size() || v < min)
        throw DistributedError(std::string("environment variable ") + name + "='" + s +
                               "' is not an integer >= " + std::to_string(min));
      return v;
    };
    e.world_size = integer("WORLD_SIZE", 1, 1);
    e.rank = integer("RANK", 0, 0);
    e.local_rank = integer("LOCAL_RANK", e.rank, 0);
    e.local_world_size = integer("LOCAL_WORLD_SIZE", e.world_size, 1);
    e.master_port = integer("MASTER_PORT", 29500, 1);
    if (e.master_port > 65535)
      throw DistributedError("environment variable MASTER_PORT=" + std::to_string(e.master_port) +
                             " is not a port");
    if (!get("MASTER_ADDR").empty()) e.master_addr = get("MASTER_ADDR");
    e.rendezvous_file = get("TOPOS_RENDEZVOUS_FILE");
    if (e.rank >= e.world_size)
      throw DistributedError("RANK=" + std::to_string(e.rank) +
                             " is not below WORLD_SIZE=" + std::to_string(e.world_size));
    if (e.world_size > 1 && std::getenv("RANK") == nullptr)
      throw DistributedError("WORLD_SIZE=" + std::to_string(e.world_size) +
                             " is set but RANK is not");
    return e;
  }
  bool loopback() const {
    return master_addr == "localhost" || master_addr == "::1" || master_addr.rfind("127.", 0) == 0;
  }
};

struct DistributedOptions {
  /// How long a collective or the rendezvous waits for the others before failing. Generous by
  /// default (as PyTorch's 30 min): rank 0 alone writes checkpoints and computes statistics.
  DistributedOptions& timeout(std::chrono::milliseconds t) { return timeout_ = t, *this; }
  /// "auto" (NCCL for CUDA tensors when built with it, else Gloo), "gloo" or "nccl".
  DistributedOptions& backend(std::string b) { return backend_ = std::move(b), *this; }
  /// Gradients are all-reduced in flat buckets of at most this many bytes, all in flight at once.
  DistributedOptions& bucket_bytes(std::int64_t b) { return bucket_bytes_ = b, *this; }
  /// The device of the tensors the collectives see (CUDA selects NCCL under "auto").
  DistributedOptions& device(torch::Device d) { return device_ = d, *this; }
  std::chrono::milliseconds timeout_{std::chrono::minutes(30)};
  std::string backend_ = "auto";
  std::int64_t bucket_bytes_ = 25 << 20;
  torch::Device device_ = torch::kCPU;
};

/// This process's membership in a data-parallel job: rank, world size and the collectives.
class Distributed {
 public:
  /// A world of one: every collective is the identity.
  Distributed() = default;

  /// Joins the job `env` describes (rendezvous with every other rank; fails after the timeout).
  explicit Distributed(const DistributedEnv& env, DistributedOptions opt = {})
      : env_(env), opt_(std::move(opt)) {
    if (env_.world_size == 1) return;
    if (opt_.backend_ != "auto" && opt_.backend_ != "gloo" && opt_.backend_ != "nccl")
      throw DistributedError("unknown distributed backend '" + opt_.backend_ +
                             "' (auto, gloo or nccl)");
    const bool want_nccl =
        opt_.backend_ == "nccl" || (opt_.backend_ == "auto" && opt_.device_.is_cuda());
    if (want_nccl && !opt_.device_.is_cuda())
      throw DistributedError("the NCCL backend needs the model on a CUDA device");
    if (want_nccl && !nccl_available())
      throw DistributedError(
          "this build of topos has no NCCL process group (needs a CUDA LibTorch with its c10d NCCL "
          "headers); use --device cpu for Gloo");
    if (!want_nccl && !gloo_available())
      throw DistributedError(
          "this build of topos has no Gloo process group: install Debian's libgloo-dev "
          "(scripts/setup.sh) and reconfigure");
    if (!want_nccl && opt_.device_.is_cuda())
      opt_.device_ = torch::kCPU;  // Gloo reduces on the host
    try {
      connect(want_nccl);
    } catch (const DistributedError&) {
      throw;
    } catch (const std::exception& e) {
      throw DistributedError(where() + "rendezvous failed (" + rendezvous_description() +
                             ", timeout " + seconds(opt_.timeout_) + "): " + first_line(e.what()));
    }
  }

  /// Joins the job described by the environment (a world of one when WORLD_SIZE is unset).
  static std::unique_ptr<Distributed> from_environment(DistributedOptions opt = {}) {
    return std::make_unique<Distributed>(DistributedEnv::from_environment(), std::move(opt));
  }

  Distributed(const Distributed&) = delete;
  Distributed& operator=(const Distributed&) = delete;
  ~Distributed() {
    // A failed Gloo group would drain its queue (waiting out every timeout) and join its threads
    // in its destructor; after a failure the job is over, so let the process exit without that.
    if (failed_) {
      // Never destroyed, but kept reachable until exit, so LeakSanitizer reports no leak.
      static std::mutex mutex;
      static auto* abandoned = new std::vector<void*>();
      const std::lock_guard<std::mutex> lock(mutex);
      abandoned->push_back(backend_.release());
      abandoned->push_back(store_.release());
    }
  }

  int rank() const { return env_.rank; }
  int world_size() const { return env_.world_size; }
  int local_rank() const { return env_.local_rank; }
  int local_world_size() const { return env_.local_world_size; }
  bool is_main() const { return env_.rank == 0; }
  const DistributedEnv& env() const { return env_; }
  /// "gloo", "nccl", or "none" for a world of one.
  std::string backend_name() const { return backend_ ? backend_->name() : std::string("none"); }
  std::chrono::milliseconds timeout() const { return opt_.timeout_; }

  /// Sums each tensor over the ranks, in place (any device; staged through the backend's).
  void all_reduce_sum_(std::vector<torch::Tensor>& tensors, const char* what = "all-reduce") {
    if (!backend_ || tensors.empty()) return;
    std::vector<torch::Tensor> staged;
    for (auto& t : tensors) staged.push_back(t.to(opt_.device_).contiguous());
    std::vector<c10::intrusive_ptr<c10d::Work>> works;
    run(what, [&] {
      for (auto& s : staged) works.push_back(backend_->all_reduce(s));
      for (auto& w : works) w->wait(opt_.timeout_);
    });
    for (std::size_t i = 0; i < tensors.size(); ++i)
      if (!staged[i].is_same(tensors[i])) tensors[i].copy_(staged[i]);
  }

  /// Sums values over the ranks (loss sums, counts): the same on every rank afterwards.
  std::vector<double> all_reduce_sum(std::vector<double> values, const char* what = "all-reduce") {
    auto t = torch::tensor(values, torch::kDouble);
    std::vector<torch::Tensor> v{t};
    all_reduce_sum_(v, what);
    return std::vector<double>(v[0].data_ptr<double>(), v[0].data_ptr<double>() + v[0].numel());
  }

  /// grad ← (Σ over ranks of grad) / divisor for every parameter, in flat buckets of at most
  /// bucket_bytes (one collective each, all in flight together). A parameter without a gradient
  /// on some ranks (not reached by their trajectories, or a rank idle in the epoch's last, short
  /// step) counts as zeros there; one without a gradient on every rank keeps none, so an
  /// optimizer skips it as it would in one process.
  void average_gradients(const std::vector<torch::Tensor>& parameters, double divisor) {
    if (divisor <= 0) throw std::invalid_argument("average_gradients: divisor must be positive");
    std::vector<torch::Tensor> params;
    for (const auto& p : parameters)
      if (p.requires_grad()) params.push_back(p);
    if (!backend_) {
      if (divisor != 1.0)
        for (auto& p : params)
          if (p.grad().defined()) p.mutable_grad().div_(divisor);
      return;
    }
    auto has_grad = torch::zeros({static_cast<std::int64_t>(params.size())}, torch::kDouble);
    for (std::size_t i = 0; i < params.size(); ++i) {
      if (params[i].grad().defined())
        has_grad[static_cast<std::int64_t>(i)] = 1.0;
      else
        params[i].mutable_grad() = torch::zeros_like(params[i]);
    }
    // Buckets in parameter order (the same on every rank), split by dtype and size.
    std::vector<std::vector<std::size_t>> buckets;
    std::int64_t bytes = 0;
    for (std::size_t i = 0; i < params.size(); ++i) {
      const std::int64_t b =
          params[i].numel() * static_cast<std::int64_t>(params[i].element_size());
      if (buckets.empty() || bytes + b > opt_.bucket_bytes_ ||
          params[buckets.back().front()].scalar_type() != params[i].scalar_type())
        buckets.emplace_back(), bytes = 0;
      buckets.back().push_back(i);
      bytes += b;
    }
    std::vector<torch::Tensor> flat;
    for (const auto& bucket : buckets) {
      std::vector<torch::Tensor> parts;
      for (auto i : bucket) parts.push_back(params[i].grad().reshape(-1));
      flat.push_back(torch::cat(parts));
    }
    flat.push_back(has_grad);
    all_reduce_sum_(flat, "gradient all-reduce");
    const auto anywhere = flat.back().to(torch::kCPU);
    for (std::size_t k = 0; k < buckets.size(); ++k) {
      if (divisor != 1.0) flat[k].div_(divisor);
      std::int64_t at = 0;
      for (auto i : buckets[k]) {
        auto& g = params[i].mutable_grad();
        if (anywhere[static_cast<std::int64_t>(i)].item<double>() == 0.0)
          g = torch::Tensor();
        else
          g.copy_(flat[k].narrow(0, at, g.numel()).view_as(g));
        at += params[i].numel();
      }
    }
  }

  /// Overwrites every tensor with rank `root`'s (parameters at start: identical replicas).
  void broadcast_(const std::vector<torch::Tensor>& tensors, int root = 0,
                  const char* what = "broadcast") {
    if (!backend_ || tensors.empty()) return;
    torch::NoGradGuard no_grad;
    std::vector<torch::Tensor> staged;
    for (const auto& t : tensors) staged.push_back(t.detach().to(opt_.device_).contiguous());
    run(what, [&] {
      std::vector<c10::intrusive_ptr<c10d::Work>> works;
      for (auto& s : staged) works.push_back(backend_->broadcast(s, root));
      for (auto& w : works) w->wait(opt_.timeout_);
    });
    for (std::size_t i = 0; i < tensors.size(); ++i)
      if (!staged[i].is_same(tensors[i])) tensors[i].detach().copy_(staged[i]);
  }

  /// Rank `root`'s bytes on every rank (statistics, optimizer state, small files).
  std::string broadcast_bytes(const std::string& bytes, int root = 0,
                              const char* what = "broadcast") {
    if (!backend_) return bytes;
    auto n = torch::tensor({static_cast<std::int64_t>(bytes.size())}, torch::kLong);
    broadcast_({n}, root, what);
    const auto size = n.item<std::int64_t>();
    auto buf = torch::empty({size}, torch::kUInt8);
    if (env_.rank == root) std::memcpy(buf.data_ptr<std::uint8_t>(), bytes.data(), bytes.size());
    broadcast_({buf}, root, what);
    return std::string(reinterpret_cast<const char*>(buf.data_ptr<std::uint8_t>()),
                       static_cast<std::size_t>(size));
  }

  /// Waits until every rank arrives (or fails after the timeout).
  void barrier(const char* what = "barrier") { all_reduce_sum({0.0}, what); }

 private:
  // One interface over the concrete process groups: c10d's base class differs between LibTorch
  // versions (ProcessGroup in 1.13, Backend in 2.x), the concrete classes' calls do not.
  struct Backend {
    virtual ~Backend() = default;
    virtual c10::intrusive_ptr<c10d::Work> all_reduce(torch::Tensor& t) = 0;
    virtual c10::intrusive_ptr<c10d::Work> broadcast(torch::Tensor& t, int root) = 0;
    virtual std::string name() const = 0;
  };
  template <class Group>
  struct BackendOf : Backend {
    BackendOf(c10::intrusive_ptr<Group> g, std::string n)
        : group(std::move(g)), label(std::move(n)) {}
    c10::intrusive_ptr<c10d::Work> all_reduce(torch::Tensor& t) override {
      std::vector<torch::Tensor> v{t};
      return group->allreduce(v);
    }
    c10::intrusive_ptr<c10d::Work> broadcast(torch::Tensor& t, int root) override {
      std::vector<torch::Tensor> v{t};
      c10d::BroadcastOptions o;
      o.rootRank = root;
      return group->broadcast(v, o);
    }
    std::string name() const override { return label; }
    c10::intrusive_ptr<Group> group;
    std::string label;
  };

  static std::string seconds(std::chrono::milliseconds t) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g s", static_cast<double>(t.count()) / 1000.0);
    return buf;
  }
  static std::string first_line(const std::string& s) {
    // c10d messages carry a C++ backtrace after the first line; the first says what happened.
    const auto nl = s.find('\n');
    return nl == std::string::npos ? s : s.substr(0, nl);
  }
  std::string where() const {
    return "distributed (rank " + std::to_string(env_.rank) + " of " +
           std::to_string(env_.world_size) + "): ";
  }
  std::string rendezvous_description() const {
    return env_.rendezvous_file.empty()
               ? "TCPStore at " + env_.master_addr + ":" + std::to_string(env_.master_port)
               : "FileStore " + env_.rendezvous_file;
  }

  template <class F>
  void run(const char* what, F&& f) {
    if (failed_) throw DistributedError(where() + std::string(what) + " after an earlier failure");
    try {
      f();
    } catch (const std::exception& e) {
      failed_ = true;
      throw DistributedError(
          where() + what +
          " failed: another worker died or stopped responding within the timeout of " +
          seconds(opt_.timeout_) + " (" + first_line(e.what()) + ")");
    }
  }

  void connect(bool nccl) {
#if defined(TOPOS_WITH_C10D_GLOO) || defined(TOPOS_WITH_C10D_NCCL)
    c10::intrusive_ptr<c10d::Store> store;
    if (!env_.rendezvous_file.empty()) {
      store = c10::make_intrusive<c10d::FileStore>(env_.rendezvous_file, env_.world_size);
    } else {
      c10d::TCPStoreOptions o;
      o.port = static_cast<std::uint16_t>(env_.master_port);
      o.isServer = env_.rank == 0;
      o.numWorkers = static_cast<std::size_t>(env_.world_size);
      o.waitWorkers = true;
      o.timeout = opt_.timeout_;
      store = c10::make_intrusive<c10d::TCPStore>(env_.master_addr, o);
    }
    store->setTimeout(opt_.timeout_);
    store_ = store;
    auto prefixed = c10::make_intrusive<c10d::PrefixStore>("topos", store);
    if (nccl) {
#ifdef TOPOS_WITH_C10D_NCCL
      auto o = c10d::ProcessGroupNCCL::Options::create();
      o->timeout = opt_.timeout_;
      backend_ = std::make_unique<BackendOf<c10d::ProcessGroupNCCL>>(
          c10::make_intrusive<c10d::ProcessGroupNCCL>(prefixed, env_.rank, env_.world_size, o),
          "nccl");
#endif
    } else {
#ifdef TOPOS_WITH_C10D_GLOO
      auto o = c10d::ProcessGroupGloo::Options::create(opt_.timeout_);
      // GLOO_SOCKET_IFNAME picks the interface as in PyTorch; a job on this machine stays on the
      // loopback interface, others use the address the host name resolves to.
      if (const char* ifname = std::getenv("GLOO_SOCKET_IFNAME"); ifname && *ifname)
        o->devices.push_back(c10d::ProcessGroupGloo::createDeviceForInterface(ifname));
      else if (env_.loopback())
        o->devices.push_back(c10d::ProcessGroupGloo::createDeviceForHostname("127.0.0.1"));
      else
        o->devices.push_back(c10d::ProcessGroupGloo::createDefaultDevice());
      o->threads = 2;
      backend_ = std::make_unique<BackendOf<c10d::ProcessGroupGloo>>(
          c10::make_intrusive<c10d::ProcessGroupGloo>(prefixed, env_.rank, env_.world_size, o),
          "gloo");
#endif
    }
#else
    (void)nccl;
#endif
  }

  DistributedEnv env_;
  DistributedOptions opt_;
  bool failed_ = false;
#if defined(TOPOS_WITH_C10D_GLOO) || defined(TOPOS_WITH_C10D_NCCL)
  c10::intrusive_ptr<c10d::Store> store_;
#else
  struct NoStore {
    void* release() { return nullptr; }
  } store_;
#endif
  std::unique_ptr<Backend> backend_;
};

// ---- deterministic epoch sharding ------------------------------------------------------------

/// The order of `n` items in `epoch` for `seed`: a Fisher–Yates shuffle driven by a
/// std::mt19937_64 (whose output the standard fixes), so every rank, machine and world size
/// computes the same order.
inline std::vector<std::int64_t> epoch_order(std::int64_t n, std::uint64_t seed,
                                             std::int64_t epoch) {
  std::vector<std::int64_t> order(static_cast<std::size_t>(n));
  std::iota(order.begin(), order.end(), std::int64_t{0});
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ULL + static_cast<std::uint64_t>(epoch));
  for (std::int64_t i = n - 1; i > 0; --i) {
    const auto j = static_cast<std::int64_t>(rng() % static_cast<std::uint64_t>(i + 1));
    std::swap(order[static_cast<std::size_t>(i)], order[static_cast<std::size_t>(j)]);
  }
  return order;
}

/// Optimizer steps in an epoch of `n` items when each step takes `per_rank` items on each of
/// `world` ranks (the last step may be short).
inline std::int64_t steps_per_epoch(std::int64_t n, int world, int per_rank) {
  const std::int64_t per_step = static_cast<std::int64_t>(world) * per_rank;
  return (n + per_step - 1) / per_step;
}

/// The items of step `step` of an epoch: positions [step·W·K, (step+1)·W·K) of `order`, rank r
/// taking its K consecutive ones; `total` is the step's item count over all ranks (W·K except
/// in a short last step), the divisor of the averaged gradient.
struct StepShard {
  std::vector<std::int64_t> items;  ///< this rank's
  std::int64_t total = 0;
};
inline StepShard step_shard(const std::vector<std::int64_t>& order, std::int64_t step, int world,
                            int rank, int per_rank) {
  const auto n = static_cast<std::int64_t>(order.size());
  const std::int64_t begin = step * world * per_rank,
                     end = std::min(n, begin + static_cast<std::int64_t>(world) * per_rank);
  StepShard s;
  s.total = std::max<std::int64_t>(0, end - begin);
  for (std::int64_t k = begin + static_cast<std::int64_t>(rank) * per_rank;
       k < std::min(end, begin + static_cast<std::int64_t>(rank + 1) * per_rank); ++k)
    s.items.push_back(order[static_cast<std::size_t>(k)]);
  return s;
}

}  // namespace topos::nn
