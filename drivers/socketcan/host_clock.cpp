#include "turncal/drivers/host_clock.hpp"

namespace turncal::socketcan {

std::int64_t HostClock::read_clock(clockid_t id) {
  timespec ts{};
  ::clock_gettime(id, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

HostClock::HostClock(Read read) : read_(read) {
  anchor();
}

HostClock::Pair HostClock::read_pair() const {
  // monotonic, realtime, monotonic: a realtime read between two monotonic
  // ones close together (a preemption between them would pass for a step)
  Pair best{};
  std::int64_t best_gap = -1;
  for (int k = 0; k < kPairTries; ++k) {
    const std::int64_t m1 = read_(CLOCK_MONOTONIC);
    const std::int64_t r = read_(CLOCK_REALTIME);
    const std::int64_t m2 = read_(CLOCK_MONOTONIC);
    const std::int64_t gap = m2 - m1;
    if (best_gap < 0 || gap < best_gap) {
      best = {m1 + gap / 2, r};
      best_gap = gap;
    }
    if (gap <= kPairGapNs) break;
  }
  return best;
}

void HostClock::anchor() {
  const Pair p = read_pair();
  mono0_ = p.mono;
  rt0_ = p.real;
  offset_ = before_ = 0;
  steps_ = unknown_ = 0;
  last_look_ns_ = step_floor_ns_ = rt0_;
}

std::int64_t HostClock::now_ns() const {
  return rt0_ + (read_(CLOCK_MONOTONIC) - mono0_);
}

bool HostClock::observe() {
  const Pair p = read_pair();
  const std::int64_t now = rt0_ + (p.mono - mono0_);
  const std::int64_t off = p.real - now;
  const std::int64_t prev_look = last_look_ns_;
  last_look_ns_ = now;
  if (off - offset_ < kStepNs && offset_ - off < kStepNs) return false;
  before_ = offset_;
  offset_ = off;
  // every frame stamped before the look that still had the old offset was
  // read by then: a frame that reads as older was stamped before the step
  step_floor_ns_ = prev_look;
  ++steps_;
  return true;
}

std::int64_t HostClock::from_realtime(std::int64_t realtime_ns) {
  const std::int64_t now = now_ns();
  // (the offset is read to within kStepNs)
  auto fits = [&](std::int64_t t) { return t <= now + kStepNs && t >= now - kMaxAgeNs; };
  const std::int64_t t = realtime_ns - offset_;
  if (steps_ == 0) return t;
  // stamped before the last step, read after it: on the offset before it
  if (!fits(t) || t < step_floor_ns_ - kStepNs) {
    if (const std::int64_t b = realtime_ns - before_; fits(b)) return b;
    if (fits(t)) return t;
    ++unknown_;
    return now;
  }
  return t;
}

}  // namespace turncal::socketcan
