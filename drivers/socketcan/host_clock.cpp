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

void HostClock::anchor() {
  mono0_ = read_(CLOCK_MONOTONIC);
  rt0_ = read_(CLOCK_REALTIME);
  offset_ = before_ = 0;
  steps_ = 0;
}

std::int64_t HostClock::now_ns() const {
  return rt0_ + (read_(CLOCK_MONOTONIC) - mono0_);
}

bool HostClock::observe() {
  const std::int64_t now = now_ns();
  const std::int64_t off = read_(CLOCK_REALTIME) - now;
  if (off - offset_ < kStepNs && offset_ - off < kStepNs) return false;
  before_ = offset_;
  offset_ = off;
  ++steps_;
  return true;
}

std::int64_t HostClock::from_realtime(std::int64_t realtime_ns) {
  const std::int64_t now = now_ns();
  // (the offset is read to within the reading of two clocks: kStepNs)
  auto fits = [&](std::int64_t t) { return t <= now + kStepNs && t >= now - kMaxAgeNs; };
  const std::int64_t t = realtime_ns - offset_;
  if (fits(t) || steps_ == 0) return t;
  // stamped before the last step, read after it
  if (const std::int64_t b = realtime_ns - before_; fits(b)) return b;
  ++unknown_;
  return now;
}

}  // namespace turncal::socketcan
