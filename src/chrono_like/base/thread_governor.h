// The CPU stages' team size under load: between the full OpenMP team and one thread, chosen from measured step
// times. OpenMP teams synchronise at barriers many times per step (every solver iteration); when other processes
// take the cores, a descheduled team member holds every barrier for a scheduler time slice and a step that takes
// 35 ms alone can take a second. A single thread degrades gracefully instead (its share of a core). The governor
// keeps an exponential average of the step time of the team size in use and, now and then, tries the other one
// for one step; it switches when the other is clearly faster (below kSwitchRatio of the average). Each time the
// probe loses, the probe interval grows by the probe's cost ratio (at least 2x, up to kMaxInterval steps), so an
// idle machine pays one single-threaded step in hundreds and a loaded one one collapsed team step in hundreds; a
// step much slower than the average (load just arrived) probes at once.
// The results do not depend on the team size (every reduction is blocked and ordered, solver.h), so switching
// changes the speed only.
#pragma once

#include <cstdint>

namespace dvi {

class ThreadGovernor {
 public:
  static constexpr double kSwitchRatio = 0.8;   // the other team size must be this much faster to switch
  static constexpr double kJumpRatio = 3.0;     // a step this much slower than the average triggers a probe
  static constexpr int64_t kFirstInterval = 8;  // steps between probes after a switch
  static constexpr int64_t kMaxInterval = 512;
  static constexpr double kAverageWeight = 0.25;  // of the newest step in the running average

  // The team size for the next step, 1 or full (full <= 1: always 1).
  int choose(int full) {
    full_ = full;
    if (full <= 1) return 1;
    probing_ = step_ >= next_probe_ && step_ >= kWarmup;
    return teamFor(probing_ ? 1 - mode_ : mode_);
  }

  // The measured wall time of the step just run with `used` threads.
  void record(int used, double seconds) {
    ++step_;
    if (full_ <= 1 || step_ <= kWarmup) return;
    const int m = used > 1 ? 1 : 0;
    if (!probing_) {
      if (avg_[m] > 0 && seconds > kJumpRatio * avg_[m]) next_probe_ = step_;  // load arrived: probe next step
      avg_[m] = avg_[m] > 0 ? (1 - kAverageWeight) * avg_[m] + kAverageWeight * seconds : seconds;
      return;
    }
    probing_ = false;
    if (avg_[mode_] > 0 && seconds < kSwitchRatio * avg_[mode_]) {
      mode_ = m;
      ++switches_;
      avg_[m] = seconds;
      interval_ = kFirstInterval;
    } else {
      // The probe lost: wait longer, in proportion to how much it cost (a probe 15x slower than the average waits
      // 15x longer), so that probing a collapsed team costs a bounded, shrinking share of the run.
      const double ratio = avg_[mode_] > 0 ? seconds / avg_[mode_] : 2.0;
      const int64_t grow = ratio > 2 ? int64_t(ratio + 0.5) : 2;
      interval_ = interval_ * grow < kMaxInterval ? interval_ * grow : kMaxInterval;
    }
    next_probe_ = step_ + interval_;
  }

  bool singleThreaded() const { return mode_ == 0; }  // the governor is running one thread now
  int64_t switches() const { return switches_; }

 private:
  static constexpr int64_t kWarmup = 2;  // the first steps allocate and fill caches: not measured
  int teamFor(int mode) const { return mode == 1 ? full_ : 1; }

  int full_ = 1;
  int mode_ = 1;  // 1 the full team, 0 one thread
  bool probing_ = false;
  double avg_[2] = {0, 0};
  int64_t step_ = 0, next_probe_ = kFirstInterval, interval_ = kFirstInterval, switches_ = 0;
};

}  // namespace dvi
