// The host clock: realtime at the anchor plus monotonic time, and the
// kernel's realtime receive stamps taken onto it across steps of the
// realtime clock. The two system clocks are a seam here.
#include <doctest/doctest.h>

#include <initializer_list>

#include "turncal/drivers/host_clock.hpp"

using turncal::socketcan::HostClock;

namespace {

// the system's clocks, as a test sets them (ns)
std::int64_t g_mono = 0;
std::int64_t g_real = 0;

std::int64_t fake_read(clockid_t id) {
  return id == CLOCK_MONOTONIC ? g_mono : g_real;
}

constexpr std::int64_t kS = 1'000'000'000;
constexpr std::int64_t kHour = 3600 * kS;

/// Both clocks on by `dt`.
void pass(std::int64_t dt) {
  g_mono += dt;
  g_real += dt;
}

}  // namespace

TEST_SUITE("host clock") {
  TEST_CASE("a step of the realtime clock moves neither the clock nor a frame's stamp") {
    g_mono = 5 * kS;
    g_real = 1'700'000'000 * kS;
    HostClock c(fake_read);
    const std::int64_t t0 = c.now_ns();
    CHECK(t0 == 1'700'000'000 * kS);
    pass(2 * kS);
    CHECK(c.now_ns() == t0 + 2 * kS);
    // a frame received 3 ms ago, stamped on the realtime clock
    CHECK_FALSE(c.observe());
    CHECK(c.from_realtime(g_real - 3'000'000) == c.now_ns() - 3'000'000);
    // an hour either way, and 2 s (NTP's usual step: the frame's reading on
    // the new offset alone would be 2 s in the past, yet within 10 s of now)
    for (const std::int64_t step : {kHour, -kHour, 2 * kS, -2 * kS}) {
      CAPTURE(step);
      HostClock h(fake_read);
      pass(kS);
      CHECK_FALSE(h.observe());  // a batch read: every frame until now is in
      pass(1'000'000);
      const std::int64_t stamped = g_real;     // received 1 ms after that read,
      const std::int64_t expect = h.now_ns();  // at this time of the clock
      pass(3'000'000);
      g_real += step;  // the step, before the frame is read
      pass(1'000'000);
      CHECK(h.now_ns() == expect + 4'000'000);  // monotonic: the step is not in it
      CHECK(h.observe());
      CHECK(h.steps() == 1);
      CHECK(h.realtime_offset_ns() == step);
      // read after the step: the frame from before it keeps its time
      CHECK(h.from_realtime(stamped) == expect);
      // and one received after it
      CHECK(h.from_realtime(g_real - 2'000'000) == h.now_ns() - 2'000'000);
      CHECK(h.unknown_stamps() == 0);
      // a stamp neither offset makes sense of: the time it was read, counted
      CHECK(h.from_realtime(g_real + 20 * kS) == h.now_ns());
      CHECK(h.unknown_stamps() == 1);
      // the next run is anchored on the realtime clock as it reads now
      h.anchor();
      CHECK(h.now_ns() == g_real);
      CHECK(h.steps() == 0);
      g_real -= step;  // back where it was, for the next case
    }
  }

  TEST_CASE("reading two clocks a little apart is no step") {
    g_mono = kS;
    g_real = 1'700'000'000 * kS;
    HostClock c(fake_read);
    g_real += HostClock::kStepNs - 1;  // under the threshold: noise of the reading
    CHECK_FALSE(c.observe());
    CHECK(c.realtime_offset_ns() == 0);
    g_real += 2;  // over it
    CHECK(c.observe());
    CHECK(c.realtime_offset_ns() == HostClock::kStepNs + 1);
  }
}
