// topos/util/memory.hpp
// The process's resident memory: current and peak (high-water mark) in MB, and a reset of the
// peak so that it can be read per training step. Linux /proc only; elsewhere the readers
// return -1 and the reset does nothing. std only.
#pragma once

#include <fstream>
#include <string>

namespace topos {

namespace detail {
inline double proc_status_mb(const char* key) {
  std::ifstream in("/proc/self/status");
  std::string line;
  const std::string k = std::string(key) + ":";
  while (std::getline(in, line))
    if (line.compare(0, k.size(), k) == 0) return std::stod(line.substr(k.size())) / 1024.0;  // kB
  return -1;
}
}  // namespace detail

/// Resident memory now (MB), or -1 where unknown.
inline double current_rss_mb() {
  return detail::proc_status_mb("VmRSS");
}

/// Peak resident memory since the start or the last reset_peak_rss() (MB), or -1.
inline double peak_rss_mb() {
  return detail::proc_status_mb("VmHWM");
}

/// Starts a new peak at the current resident memory (Linux >= 4.0: writes 5 to clear_refs).
/// Returns false where the kernel does not allow it.
inline bool reset_peak_rss() {
  std::ofstream out("/proc/self/clear_refs");
  if (!out) return false;
  out << "5";
  out.flush();
  return static_cast<bool>(out);
}

}  // namespace topos
