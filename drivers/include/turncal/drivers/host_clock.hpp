// The host's time for a run: the realtime clock as it read at the anchor
// (start-up, and each run's start) plus the monotonic time since. A step of
// the realtime clock (NTP at boot on a stand PC without a battery-backed
// clock, an operator's `date`) moves no deadline, no staleness check, no
// schedule and no log time; the next run is anchored afresh.
//
// The kernel stamps received frames on CLOCK_REALTIME (SO_TIMESTAMPNS), so
// each stamp is taken onto this clock through the realtime clock's offset
// from it. A frame stamped before a step but read after it would be moved
// by the step: a stamp that lands outside [now - 10 s, now], or before the
// last look at the clock ahead of the step (when every frame stamped until
// then had been read), is taken through the offset before the step, and
// failing both is the time it was read (counted: `unknown_stamps`).
#pragma once

#include <time.h>

#include <cstdint>

namespace turncal::socketcan {

class HostClock {
 public:
  /// Reads a clock, ns (clock_gettime); a seam for tests.
  using Read = std::int64_t (*)(clockid_t);
  static std::int64_t read_clock(clockid_t id);
  /// A step of the realtime clock smaller than this is noise of reading
  /// two clocks, not a step (NTP steps are 128 ms and more; less it slews).
  static constexpr std::int64_t kStepNs = 10'000'000;
  /// The realtime clock is read between two monotonic reads at most this far
  /// apart (tried a few times; the closest pair is taken).
  static constexpr std::int64_t kPairGapNs = 50'000;
  static constexpr int kPairTries = 4;
  /// The oldest a received frame can be when it is read.
  static constexpr std::int64_t kMaxAgeNs = 10'000'000'000;

  explicit HostClock(Read read = read_clock);
  /// Realtime now, and monotonic from here on; the steps and the unknown
  /// stamps seen are forgotten.
  void anchor();
  /// ns since the Unix epoch, as the realtime clock read at the anchor plus
  /// the monotonic time since.
  [[nodiscard]] std::int64_t now_ns() const;
  /// Reads the realtime clock's offset from this one; returns true when it
  /// stepped since the last look. Call before taking a batch's stamps.
  bool observe();
  /// A kernel realtime stamp on this clock.
  [[nodiscard]] std::int64_t from_realtime(std::int64_t realtime_ns);
  /// realtime - this clock, ns, at the last observe().
  [[nodiscard]] std::int64_t realtime_offset_ns() const { return offset_; }
  [[nodiscard]] std::uint64_t steps() const { return steps_; }
  [[nodiscard]] std::uint64_t unknown_stamps() const { return unknown_; }

 private:
  struct Pair {
    std::int64_t mono, real;
  };
  [[nodiscard]] Pair read_pair() const;
  Read read_;
  std::int64_t rt0_ = 0, mono0_ = 0;
  std::int64_t last_look_ns_ = 0;         ///< this clock at the last observe()
  std::int64_t step_floor_ns_ = 0;        ///< the look before the last step
  std::int64_t offset_ = 0, before_ = 0;  ///< now, and before the last step
  std::uint64_t steps_ = 0, unknown_ = 0;
};

}  // namespace turncal::socketcan
