// apps/hopnet/launch.hpp
// A local launcher for data-parallel jobs, like `torchrun --nproc-per-node N` on one machine:
// starts N copies of this program with torchrun's environment (RANK, LOCAL_RANK, WORLD_SIZE,
// LOCAL_WORLD_SIZE, MASTER_ADDR=127.0.0.1) and a fresh c10d FileStore path in
// TOPOS_RENDEZVOUS_FILE, so the rendezvous listens on no network port and the workers talk over
// the loopback interface only. When a worker fails the others are stopped (SIGTERM, then SIGKILL)
// and the launcher returns the failure; when the launcher dies its workers get SIGTERM.
// POSIX + Linux (/proc/self/exe, PR_SET_PDEATHSIG); std only otherwise.
#pragma once

#include "topos/util/read_file.hpp"

#include <signal.h>
#include <stdlib.h>
#include <sys/prctl.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace topos {

/// This process's command line (argv), read from /proc/self/cmdline.
inline std::vector<std::string> self_command_line() {
  std::string all;
  topos::read_file("/proc/self/cmdline", all);
  std::vector<std::string> argv;
  std::string cur;
  for (char c : all) {
    if (c == '\0')
      argv.push_back(cur), cur.clear();
    else
      cur += c;
  }
  if (!cur.empty()) argv.push_back(cur);
  if (argv.empty())
    throw std::runtime_error("cannot read this program's command line from /proc/self/cmdline");
  return argv;
}

/// Runs `argv` (argv[0] is replaced by this executable) as `nproc` local workers and waits for
/// them. Returns 0 when every worker succeeds, else the first failure's exit status (128 +
/// signal for a killed worker), after stopping the rest (SIGTERM, SIGKILL after `grace`).
inline int launch_local_workers(int nproc, const std::vector<std::string>& argv,
                                std::chrono::seconds grace = std::chrono::seconds(10)) {
  if (nproc < 1) throw std::invalid_argument("launch: the number of workers must be positive");
  if (argv.empty()) throw std::invalid_argument("launch: empty command line");
  char tmpl[] = "/tmp/topos-rendezvous-XXXXXX";
  if (::mkdtemp(tmpl) == nullptr)
    throw std::runtime_error("launch: cannot create a rendezvous folder in /tmp");
  const std::filesystem::path dir(tmpl);
  const std::string store = (dir / "store").string();
  std::vector<pid_t> pids(static_cast<std::size_t>(nproc), -1);
  const pid_t parent = ::getpid();
  std::fflush(stdout), std::fflush(stderr);
  for (int r = 0; r < nproc; ++r) {
    const pid_t pid = ::fork();
    if (pid < 0) {
      for (auto p : pids)
        if (p > 0) ::kill(p, SIGKILL);
      throw std::runtime_error("launch: fork failed");
    }
    if (pid == 0) {
      ::prctl(PR_SET_PDEATHSIG, SIGTERM);
      if (::getppid() != parent) ::_exit(1);  // the launcher is already gone
      const std::string n = std::to_string(nproc), rank = std::to_string(r);
      ::setenv("RANK", rank.c_str(), 1), ::setenv("LOCAL_RANK", rank.c_str(), 1);
      ::setenv("WORLD_SIZE", n.c_str(), 1), ::setenv("LOCAL_WORLD_SIZE", n.c_str(), 1);
      ::setenv("MASTER_ADDR", "127.0.0.1", 1), ::setenv("TOPOS_RENDEZVOUS_FILE", store.c_str(), 1);
      std::vector<char*> args;
      for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
      args.push_back(nullptr);
      ::execv("/proc/self/exe", args.data());
      std::fprintf(stderr, "launch: cannot start worker %d\n", r);
      ::_exit(127);
    }
    pids[static_cast<std::size_t>(r)] = pid;
  }
  int result = 0, running = nproc;
  bool stopping = false;
  auto stop_deadline = std::chrono::steady_clock::now();
  const auto rank_of = [&](pid_t p) {
    for (int r = 0; r < nproc; ++r)
      if (pids[static_cast<std::size_t>(r)] == p) return r;
    return -1;
  };
  while (running > 0) {
    int status = 0;
    const pid_t p = ::waitpid(-1, &status, stopping ? WNOHANG : 0);
    if (p < 0) break;
    if (p == 0) {  // stopping, none exited yet
      if (std::chrono::steady_clock::now() > stop_deadline) {
        for (auto q : pids)
          if (q > 0) ::kill(q, SIGKILL);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      continue;
    }
    const int r = rank_of(p);
    if (r < 0) continue;
    pids[static_cast<std::size_t>(r)] = -1;
    --running;
    const int code = WIFEXITED(status) ? WEXITSTATUS(status)
                                       : (WIFSIGNALED(status) ? 128 + WTERMSIG(status) : 1);
    if (code != 0 && !stopping) {
      if (WIFSIGNALED(status))
        std::fprintf(stderr,
                     "launch: worker %d of %d was killed by signal %d; stopping the others\n", r,
                     nproc, WTERMSIG(status));
      else
        std::fprintf(stderr,
                     "launch: worker %d of %d failed (exit status %d); stopping the others\n", r,
                     nproc, code);
      result = code;
      stopping = true;
      stop_deadline = std::chrono::steady_clock::now() + grace;
      for (auto q : pids)
        if (q > 0) ::kill(q, SIGTERM);
    }
  }
  std::error_code ec;
  std::filesystem::remove_all(dir, ec);
  return result;
}

}  // namespace topos
