// topos/util/progress.hpp
// A terminal progress bar for long work (generation, training, evaluation): count, rate, ETA
// and a free-text status, redrawn in place at most 10 times a second on a terminal, and as
// plain lines every 10% otherwise (logs stay readable). std only.
#pragma once

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <string>

namespace topos {

class ProgressBar {
 public:
  ProgressBar(std::string label, std::int64_t total, std::string unit = "it",
              std::FILE* out = stderr)
      : label_(std::move(label)),
        unit_(std::move(unit)),
        total_(total),
        out_(out),
        tty_(isatty(fileno(out)) != 0),
        start_(clock::now()),
        last_(start_) {}
  ~ProgressBar() { finish(); }

  /// Advances by `n` (units since the bar started or was resumed at `done`).
  void update(std::int64_t n = 1, const std::string& status = {}) {
    done_ += n;
    if (!status.empty()) status_ = status;
    const auto now = clock::now();
    const bool last = done_ >= total_;
    if (tty_) {
      if (!last && now - last_ < std::chrono::milliseconds(100)) return;
    } else {
      const std::int64_t decile = total_ > 0 ? done_ * 10 / total_ : 10;
      if (!last && decile == printed_decile_) return;
      printed_decile_ = decile;
    }
    last_ = now;
    draw(last);
  }
  void set_status(const std::string& s) { status_ = s; }
  /// Units already done before this run (a resumed job): counted in the bar, not in the rate.
  void resume_from(std::int64_t done) { done_ = offset_ = done; }
  double elapsed() const { return std::chrono::duration<double>(clock::now() - start_).count(); }
  double rate() const {
    return elapsed() > 0 ? static_cast<double>(done_ - offset_) / elapsed() : 0.0;
  }
  void finish() {
    if (finished_) return;
    finished_ = true;
    if (done_ < total_ || tty_ || printed_decile_ < 10) draw(true);
  }

 private:
  using clock = std::chrono::steady_clock;
  std::string label_, unit_, status_;
  std::int64_t total_, done_ = 0, offset_ = 0, printed_decile_ = -1;
  std::FILE* out_;
  bool tty_, finished_ = false;
  clock::time_point start_, last_;

  static std::string hms(double s) {
    if (!(s >= 0) || s > 1e7) return "--:--";
    const long t = static_cast<long>(s + 0.5);
    char b[32];
    if (t >= 3600)
      std::snprintf(b, sizeof b, "%ld:%02ld:%02ld", t / 3600, t / 60 % 60, t % 60);
    else
      std::snprintf(b, sizeof b, "%02ld:%02ld", t / 60, t % 60);
    return b;
  }
  void draw(bool final_line) {
    const double frac = total_ > 0 ? static_cast<double>(done_) / static_cast<double>(total_) : 1.0;
    const int width = 24, fill = static_cast<int>(frac * width + 0.5);
    std::string bar(static_cast<std::size_t>(std::max(0, std::min(width, fill))), '#');
    bar.resize(width, '.');
    const double r = rate();
    const double eta = r > 0 ? static_cast<double>(total_ - done_) / r : -1;
    std::fprintf(out_, "%s%s [%s] %lld/%lld %.2f %s/s elapsed %s eta %s%s%s%s",
                 tty_ ? "\r\033[K" : "", label_.c_str(), bar.c_str(), static_cast<long long>(done_),
                 static_cast<long long>(total_), r, unit_.c_str(), hms(elapsed()).c_str(),
                 hms(eta).c_str(), status_.empty() ? "" : "  ", status_.c_str(),
                 (!tty_ || final_line) ? "\n" : "");
    std::fflush(out_);
  }
};

}  // namespace topos
