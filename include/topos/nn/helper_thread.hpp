// topos/nn/helper_thread.hpp
// HelperThread: one more thread that a forward hands a job to and waits for. After each job it
// spins for a while before it sleeps, so that a handoff while it is busy costs well under a
// microsecond: a condition variable's wake-up takes 10-20 µs on a VM, as long as a small step's
// arithmetic. OperatorNetwork runs a parallel group's independent steps on such threads
// (OperatorNetworkImpl::step_threads). Standard library only.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <utility>

namespace topos::nn::detail {

class HelperThread {
 public:
  /// `spin`: how long the thread polls for the next job after one ends before it sleeps.
  explicit HelperThread(std::chrono::microseconds spin = std::chrono::microseconds(200))
      : spin_(spin), thread_([this] { loop(); }) {}
  HelperThread(const HelperThread&) = delete;
  HelperThread& operator=(const HelperThread&) = delete;
  ~HelperThread() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_.store(true, std::memory_order_release);
    }
    wake_.notify_one();
    thread_.join();
  }

  /// Starts `job` on the helper. One job at a time: wait() for it before posting the next.
  void post(std::function<void()> job) {
    if (posted_.load(std::memory_order_relaxed) != done_.load(std::memory_order_acquire))
      throw std::logic_error("HelperThread::post: the previous job was not waited for");
    job_ = std::move(job);
    error_ = nullptr;
    posted_.fetch_add(1, std::memory_order_release);
    // A helper between its last check and its sleep holds the mutex: taking it here means the
    // notification cannot fall between the two.
    { std::lock_guard<std::mutex> lock(mutex_); }
    wake_.notify_one();
  }

  /// Waits for the job posted last and rethrows what it threw.
  void wait() {
    const auto target = posted_.load(std::memory_order_relaxed);
    for (unsigned n = 1; done_.load(std::memory_order_acquire) != target; ++n) {
      pause();
      if (n % 1024 == 0) std::this_thread::yield();  // the helper may share this core
    }
    if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
  }

 private:
  static void pause() {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#endif
  }

  void loop() {
    std::uint64_t seen = 0;
    for (;;) {
      const auto until = std::chrono::steady_clock::now() + spin_;
      for (unsigned n = 1; posted_.load(std::memory_order_acquire) == seen; ++n) {
        if (stop_.load(std::memory_order_acquire)) return;
        pause();
        if (n % 64 == 0 && std::chrono::steady_clock::now() > until) {
          std::unique_lock<std::mutex> lock(mutex_);
          wake_.wait(lock, [&] {
            return stop_.load(std::memory_order_acquire) ||
                   posted_.load(std::memory_order_acquire) != seen;
          });
        }
      }
      seen = posted_.load(std::memory_order_acquire);
      try {
        job_();
      } catch (...) {
        error_ = std::current_exception();
      }
      job_ = nullptr;  // what the job captured goes now, not with the next post
      done_.store(seen, std::memory_order_release);
    }
  }

  std::chrono::microseconds spin_;
  std::function<void()> job_;  // written by post, read by the helper between the two counters
  std::exception_ptr error_;   // likewise
  std::atomic<std::uint64_t> posted_{0}, done_{0};
  std::atomic<bool> stop_{false};
  std::mutex mutex_;
  std::condition_variable wake_;
  std::thread thread_;  // last: started once the members it uses exist
};

}  // namespace topos::nn::detail
