// topos/util/csv_log.hpp
// CSV logs that a resumed run continues: the rows written after the last committed state
// (and a row cut short by a kill) are dropped before appending again. std only.
#pragma once

#include "topos/io/atomic_file.hpp"
#include "topos/util/read_file.hpp"

#include <cstdint>
#include <cstdlib>
#include <string>

namespace topos {

/// Keeps the header line of the CSV log at `path` and its complete ('\n'-terminated) rows whose
/// integer field number `column` (0-based) is at most `max`; everything after the first row
/// beyond `max` goes. A missing file stays missing. Rewritten atomically.
inline void truncate_csv_log(const std::string& path, std::size_t column, std::int64_t max) {
  std::string text;
  if (!read_file(path, text)) return;
  std::string kept;
  std::size_t pos = 0;
  for (bool header = true;; header = false) {
    const auto nl = text.find('\n', pos);
    if (nl == std::string::npos) break;  // a row cut short
    const std::string row = text.substr(pos, nl + 1 - pos);
    if (!header) {
      std::size_t field = 0;
      for (std::size_t c = 0; c < column && field != std::string::npos; ++c) {
        field = row.find(',', field);
        if (field != std::string::npos) ++field;
      }
      if (field == std::string::npos) break;
      char* end = nullptr;
      const long long v = std::strtoll(row.c_str() + field, &end, 10);
      if (end == row.c_str() + field || v > max) break;
    }
    kept += row;
    pos = nl + 1;
  }
  if (kept != text) io::write_file_atomic(path, kept);
}

}  // namespace topos
