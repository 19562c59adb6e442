// Progress of a run's steps, with an ETA: a bar redrawn on stderr when stderr is a terminal; otherwise, where
// asked (lines = true: a batch job, process 0 under mpirun, whose stderr is a pipe), a line on stdout every 10 %
// or every 30 s; else nothing.
#pragma once

#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <string>

class Progress {
 public:
  using Clock = std::chrono::steady_clock;
  explicit Progress(int64_t total, bool lines = false)
      : total_(total),
        bar_(total > 0 && ::isatty(2)),
        lines_(total > 0 && lines && !bar_),
        t0_(Clock::now()),
        last_(t0_) {}
  void update(int64_t done) {
    if (!bar_ && !lines_) return;
    const auto now = Clock::now();
    const double el = std::chrono::duration<double>(now - t0_).count();
    const double frac = double(done) / double(total_);
    const double eta = done > 0 ? el * (1 - frac) / frac : 0;
    if (lines_) {
      const int tenth = int(frac * 10);
      if (done < total_ && tenth <= tenth_ && now - last_ < std::chrono::seconds(30)) return;
      tenth_ = tenth;
      last_ = now;
      std::printf("step %lld/%lld (%d%%), %.1f s, ETA %.1f s\n", (long long)done, (long long)total_, int(frac * 100),
                  el, eta);
      std::fflush(stdout);
      return;
    }
    if (done < total_ && now - last_ < std::chrono::milliseconds(100)) return;
    last_ = now;
    const int width = 30, fill = int(frac * width);
    std::string bar(size_t(fill), '=');
    bar.resize(size_t(width), ' ');
    std::fprintf(stderr, "\r[%s] %3d%%  %lld/%lld steps  ETA %.1f s ", bar.c_str(), int(frac * 100), (long long)done,
                 (long long)total_, eta);
    std::fflush(stderr);
  }
  void finish() {
    if (bar_) std::fprintf(stderr, "\r\033[K");
  }

 private:
  int64_t total_;
  bool bar_, lines_;
  int tenth_ = 0;
  Clock::time_point t0_, last_;
};
