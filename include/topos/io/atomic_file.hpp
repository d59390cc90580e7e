// topos/io/atomic_file.hpp
// Writing files so that an interruption never leaves one half-written: the bytes go to
// `<path>.tmp`, which is then renamed over `path`. Several files that belong together (a
// training checkpoint: weights, optimizer state, progress) are replaced as one with a
// FileGroup. std only (POSIX signals for the crash tests).
#pragma once

#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::io {

namespace detail {
/// Crash testing (tests/cli/crash_resume.cmake): when TOPOS_CRASH_TEST_POINT=n is set, the
/// n-th crash point of this process kills it with SIGKILL, as an out-of-memory kill or a power
/// cut would. Crash points: halfway through each write_file_atomic, and after each rename of a
/// FileGroup commit. Costs one getenv per point otherwise.
inline bool crash_test_point() {
  static const long target = [] {
    const char* v = std::getenv("TOPOS_CRASH_TEST_POINT");
    return v ? std::strtol(v, nullptr, 10) : 0L;
  }();
  static long count = 0;
  return target > 0 && ++count == target;
}
}  // namespace detail

inline void write_file_atomic(const std::string& path, const char* data, std::size_t size) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) throw std::runtime_error(tmp + ": cannot write");
    if (detail::crash_test_point()) {
      out.write(data, static_cast<std::streamsize>(size / 2));
      out.flush();
      std::raise(SIGKILL);
    }
    out.write(data, static_cast<std::streamsize>(size));
    if (!out) throw std::runtime_error(tmp + ": write failed");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    throw std::runtime_error(path + ": cannot rename the temporary file into place");
}
inline void write_file_atomic(const std::string& path, const std::string& text) {
  write_file_atomic(path, text.data(), text.size());
}

/// Completes an interrupted FileGroup commit: when `journal` exists, every file it lists whose
/// `<path>.next` remains is renamed into place, then the journal is removed. Without a journal
/// nothing happens (left-over `.next` files of an uncommitted group are simply overwritten by
/// the next one). Call it before reading the group's files.
inline void recover_file_group(const std::string& journal) {
  std::ifstream in(journal);
  if (!in) return;
  std::vector<std::string> paths;
  for (std::string p; std::getline(in, p);)
    if (!p.empty()) paths.push_back(p);
  in.close();
  for (const auto& p : paths) {
    const std::string next = p + ".next";
    if (std::ifstream(next).good() && std::rename(next.c_str(), p.c_str()) != 0)
      throw std::runtime_error(p + ": cannot rename " + next + " into place");
    if (detail::crash_test_point()) std::raise(SIGKILL);
  }
  std::remove(journal.c_str());
}

/// Files replaced together: each new file is written (atomically) as `<path>.next`
/// (stage(path) names it), then commit() writes a journal listing them, which is the moment
/// the new set counts as written, renames them into place and removes the journal. After an
/// interruption, recover_file_group(journal) leaves the old set (no journal yet) or the whole
/// new one, never a mix.
class FileGroup {
 public:
  explicit FileGroup(std::string journal) : journal_(std::move(journal)) {}
  /// Where to write `path`'s new content.
  std::string stage(const std::string& path) {
    paths_.push_back(path);
    return path + ".next";
  }
  void commit() {
    std::string list;
    for (const auto& p : paths_) list += p + "\n";
    write_file_atomic(journal_, list);
    recover_file_group(journal_);
  }

 private:
  std::string journal_;
  std::vector<std::string> paths_;
};

}  // namespace topos::io

namespace topos {
// Deprecated: the old flat names. Write io::write_file_atomic (etc.).
using io::FileGroup;
using io::recover_file_group;
using io::write_file_atomic;
}  // namespace topos
