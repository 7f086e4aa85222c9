// The run's record and the plot thinning: what keeps a one-hour run's
// memory at one copy of its velocity samples.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <limits>
#include <random>

#include "turncal/run/record.hpp"
#include "turncal/run/thin.hpp"

using namespace turncal;
using namespace turncal::run;

TEST_SUITE("record") {
  TEST_CASE("the velocity is allocated once for the expected span, and moved out, not copied") {
    Record r;
    r.expect_span(3601);  // the tactical profile: duration + 1 s
    constexpr double kHz = 100;
    const auto n = static_cast<std::size_t>(3601 * kHz);
    const est::VelocityObs* first_storage = nullptr;
    std::size_t reallocations = 0;
    for (std::size_t k = 0; k < n; ++k) {
      const double t = 1000 + static_cast<double>(k) / kHz;
      r.add(VelocitySample{t, 1.7e9 + t, 1e-3, -2e-3});
      if (k == 256) first_storage = r.velocity().data();  // after the reserve
      if (k > 256 && r.velocity().data() != first_storage) {
        ++reallocations;
        first_storage = r.velocity().data();
      }
    }
    CHECK(reallocations == 0);
    CHECK(r.velocity().capacity() >= n);
    // 2% of slack for a fast clock, no more
    CHECK(r.velocity().capacity() <= static_cast<std::size_t>(1.03 * static_cast<double>(n)));
    REQUIRE(r.velocity().size() == n);
    CHECK(r.velocity()[5].t_s == 1000.05);  // the INS clock, not yet from t0
    const est::VelocityObs* storage = r.velocity().data();
    const auto v = r.take_velocity();
    CHECK(v.data() == storage);
    CHECK(v.size() == n);
    CHECK(r.velocity().empty());
    CHECK(r.ins_clock().count() > 0);  // the clocks stay
  }

  // 100 Hz velocity on an INS clock 1000 s ahead of the host's, latency 1 ms
  // (and up to 0.4 ms of jitter); sample k is tagged tag(k)
  double on_time(int k) {
    return 1000 + 0.01 * k;
  }
  /// The record of n samples; `disagree`, where given, counts the samples
  /// after which clock_faulted() (the test without the text) disagrees
  /// with clock_fault(). `encoder`: the table clock's samples, not the INS's.
  Record record_with(int n, const std::function<double(int)>& tag,
                     const std::function<double(int)>& delay = {}, double time_scale = 1,
                     int* disagree = nullptr, bool encoder = false, double late_floor_s = 0) {
    Record r;
    r.set_time_scale(time_scale, late_floor_s);
    for (int k = 0; k < n; ++k) {
      const double host = 1.7e9 + 0.01 * k + 1e-3 + 2e-4 * (k % 3) + (delay ? delay(k) : 0.0);
      if (encoder)
        r.add(EncoderSample{tag(k), host, 0});
      else
        r.add(VelocitySample{tag(k), host, 0, 0});
      if (disagree != nullptr) *disagree += r.clock_faulted() == r.clock_fault().empty();
    }
    return r;
  }
  /// The number after "by " in a fault's reason.
  double jump_of(const std::string& reason) {
    const auto at = reason.find(" by ");
    return at == std::string::npos ? std::nan("") : std::strtod(reason.c_str() + at + 4, nullptr);
  }

  TEST_CASE("time tags: a clock that jumps for a moment loses those samples, not the run") {
    // at 20 s, 10 tags jump 0.3 s ahead; at 25 s, 10 repeat the one before
    const Record r = record_with(3000, [](int k) {
      if (k >= 2000 && k < 2010) return on_time(k) + 0.3;
      if (k >= 2500 && k < 2510) return on_time(2499);
      return on_time(k);
    });
    CHECK(r.velocity_tags().dropped() == 20);
    CHECK(r.velocity().size() == 2980);
    CHECK(r.clock_fault().empty());
    CHECK_FALSE(r.clock_faulted());
    for (std::size_t i = 1; i < r.velocity().size(); ++i)
      REQUIRE(r.velocity()[i].t_s > r.velocity()[i - 1].t_s);
  }

  TEST_CASE("time tags: a clock that stays jumped fails, whichever way it jumped, saying how far") {
    struct Case {
      double jump_s;
      int at;  ///< the first jumped sample
      const char* reason;
    };
    // ahead: every later tag is after its receipt; back by 0.8 s: 0.8 s of
    // tags before the last one kept; back by 0.2 s: 0.2 s of those, then
    // every frame 0.2 s late. At 20 s the clock's fit is the reference; at
    // 3 s (before it spans 10 s) the lowest offset seen.
    // The same for the table's clock (its encoder samples).
    for (const Case& c : {Case{0.3, 2000, "the INS clock jumped ahead by "},
                          Case{-0.8, 2000, "the INS clock stepped back by "},
                          Case{-0.2, 2000, "the INS clock fell behind by "},
                          Case{0.3, 300, "the INS clock jumped ahead by "},
                          Case{-0.2, 300, "the INS clock fell behind by "},
                          Case{0.3, 2000, "the table clock jumped ahead by "},
                          Case{-0.8, 2000, "the table clock stepped back by "},
                          Case{-0.2, 2000, "the table clock fell behind by "}}) {
      CAPTURE(c.jump_s);
      CAPTURE(c.at);
      const bool encoder = std::string(c.reason).find("table") != std::string::npos;
      CAPTURE(encoder);
      int disagree = 0;
      const Record r = record_with(
          3000, [&](int k) { return on_time(k) + (k >= c.at ? c.jump_s : 0.0); }, {}, 1, &disagree,
          encoder);
      const std::string why = r.clock_fault();
      CAPTURE(why);
      CHECK(why.find(c.reason) == 0);
      CHECK(r.clock_faulted());
      // the test without the text agrees with it, before the fault and after
      CHECK(disagree == 0);
      // within the latency's jitter (0.4 ms) and the message's 1 ms
      CHECK(std::abs(jump_of(why) - std::abs(c.jump_s)) < 2e-3);
      CHECK((encoder ? r.encoder_tags() : r.velocity_tags()).dropped() > 0);
    }
    // 45 ms back: within the gate, kept (the late fault needs over 50 ms)
    const Record small =
        record_with(3000, [](int k) { return on_time(k) + (k >= 2000 ? -0.045 : 0.0); });
    CHECK(small.clock_fault().empty());
    CHECK(small.velocity_tags().dropped() == 4);
  }

  TEST_CASE("time tags: frames that come late for long with their tags right are kept") {
    // 3 s of every frame 0.2 s late (a bus busy above the INS, a transmit
    // backlog), arriving in order: no tag went back, so no clock fault
    const Record r =
        record_with(5000, on_time, [](int k) { return k >= 2000 && k < 2300 ? 0.2 : 0.0; });
    CHECK(r.clock_fault().empty());
    CHECK(r.velocity_tags().dropped() == 0);
    CHECK(r.velocity().size() == 5000);
  }

  TEST_CASE("time tags: a clock that steps back in a pause of its frames fails after 10 s late") {
    // no frame for 0.5 s at 20 s; the clock 0.2 s back after it: no tag goes
    // back, but every frame comes 0.2 s later than its tag says
    Record r;
    int late_from = -1, disagree = 0;
    for (int k = 0; k < 4000; ++k) {
      if (k >= 2000 && k < 2050) continue;
      r.add(VelocitySample{on_time(k) - (k >= 2050 ? 0.2 : 0.0), 1.7e9 + 0.01 * k + 1e-3, 0, 0});
      if (late_from < 0 && !r.clock_fault().empty()) late_from = k;
      // the test without the text agrees with it, before the fault and after
      disagree += r.clock_faulted() == r.clock_fault().empty();
    }
    CHECK(disagree == 0);
    CAPTURE(r.clock_fault());
    CHECK(r.clock_fault().find("the INS clock fell behind by 0.200 s: every frame for 10 s") == 0);
    CHECK(late_from == 1999 + 1000);  // 10 s after the last frame on time
    CHECK(r.velocity_tags().dropped() == 0);
  }

  TEST_CASE("time tags: the gate is real time, a frame's delay; stand seconds are scaled") {
    // at 4x a stand second is 0.25 s of real time: the 50 ms gate is 0.2
    // stand s, so a 0.1 s jump ahead lies within it, and a 0.3 s one does not
    auto ahead = [](double by) {
      return [by](int k) { return on_time(k) + (k >= 2000 ? by : 0.0); };
    };
    CHECK(record_with(3000, ahead(0.1), {}, 4).velocity_tags().dropped() == 0);
    CHECK(record_with(3000, ahead(0.1), {}, 1).velocity_tags().dropped() == 1000);
    const Record r = record_with(3000, ahead(0.3), {}, 4);
    CHECK(r.clock_fault().find("the INS clock jumped ahead by 0.3") == 0);
  }

  TEST_CASE(
      "time tags: a stand run faster than real time may fall behind by its real-time floor, no "
      "more") {
    // at 5x with a 1 s floor (5 stand s): every frame from 20 s on comes
    // 1.5 stand s (0.3 s real) late, a busy host's lag, for 30 s: kept,
    // no fault. Without the floor the same lag is a clock that fell behind
    // (the gate is 0.25 stand s), and 6 stand s (1.2 s real) is one even
    // with the floor, whose message says the gate's real 1050 ms.
    auto late = [](double by) { return [by](int k) { return k >= 2000 ? by : 0.0; }; };
    const Record kept = record_with(5000, on_time, late(1.5), 5, nullptr, false, 5.0);
    CHECK(kept.clock_fault().empty());
    CHECK(kept.velocity_tags().dropped() == 0);
    CHECK(kept.velocity().size() == 5000);
    const Record bare = record_with(5000, on_time, late(1.5), 5, nullptr, false, 0.0);
    CHECK(bare.clock_fault().find("the INS clock fell behind by 1.50") == 0);
    int disagree = 0;
    const Record far = record_with(5000, on_time, late(6.0), 5, &disagree, true, 5.0);
    CAPTURE(far.clock_fault());
    CHECK(far.clock_fault().find("the table clock fell behind by 6.00") == 0);
    CHECK(far.clock_fault().find("over 1050 ms (of real time)") != std::string::npos);
    CHECK(disagree == 0);
    // a clock that steps 0.4 stand s back (tags before the last one kept,
    // which no host's delay makes) is judged by the gate alone, floor or
    // not: late beyond 0.25 stand s (50 ms real) for 2 s after it
    const Record back = record_with(
        5000, [](int k) { return on_time(k) + (k >= 2000 ? -0.4 : 0.0); }, {}, 5, nullptr, false,
        5.0);
    CAPTURE(back.clock_fault());
    CHECK(back.clock_fault().find("the INS clock fell behind by 0.40") == 0);
    CHECK(back.clock_fault().find("every frame for 2 s came over 50 ms") != std::string::npos);
  }

  TEST_CASE("without an expected span the record grows as it must") {
    Record r;
    for (int k = 0; k < 1000; ++k) r.add(VelocitySample{k * 0.01, 1.7e9 + k * 0.01, 0, 0});
    CHECK(r.velocity().size() == 1000);
  }
}

TEST_SUITE("thinning") {
  TEST_CASE("of each half-pixel column, the first lowest and highest point, and the ends") {
    const Axis axis{0, 3600, 70, 674};
    std::mt19937 rng(11);
    std::normal_distribution<double> noise(0, 1);
    std::vector<double> x, y;
    for (int k = 0; k <= 360000; ++k) {
      x.push_back(k * 0.01);
      y.push_back(k % 50000 == 7 ? std::numeric_limits<double>::quiet_NaN()  // skipped
                                 : std::round(noise(rng) * 4) + (k == 123456 ? 100 : 0));
    }
    Thinned t(axis);
    for (std::size_t i = 0; i < x.size(); ++i) t.add(x[i], y[i]);
    const auto [tx, ty] = t.take();

    // the same by brute force: per column, the first minimum and maximum;
    // the first and the last point, the ends of the axis
    std::vector<double> ex, ey;
    auto keep = [&](std::size_t k) {
      if (ex.empty() || ex.back() != x[k]) {
        ex.push_back(x[k]);
        ey.push_back(y[k]);
      }
    };
    keep(0);
    std::size_t i = 0;
    while (i < x.size()) {
      if (!std::isfinite(y[i])) {
        ++i;
        continue;
      }
      const long c = axis.column(x[i]);
      std::size_t lo = i, hi = i, j = i;
      for (; j < x.size() && (!std::isfinite(y[j]) || axis.column(x[j]) == c); ++j) {
        if (!std::isfinite(y[j])) continue;
        if (y[j] < y[lo]) lo = j;
        if (y[j] > y[hi]) hi = j;
      }
      keep(std::min(lo, hi));
      if (lo != hi) keep(std::max(lo, hi));
      i = j;
    }
    keep(x.size() - 1);
    CHECK(tx == ex);
    CHECK(ty == ey);
    // two points per half-pixel column at most: the drawing's resolution
    CHECK(tx.size() <= 2 * (2 * 674 + 1) + 2);
    CHECK(tx.size() > 2 * 674);  // noise fills every column with two
    // the spike at sample 123456 is drawn
    CHECK(std::find(tx.begin(), tx.end(), x[123456]) != tx.end());
    // taking starts afresh
    const auto [rx, ry] = t.take();
    CHECK(rx.empty());
  }

  TEST_CASE("a constant stretch is one point per column, and the ends") {
    Thinned t(Axis{0, 10, 0, 10});
    for (int k = 0; k <= 1000; ++k) t.add(k * 0.01, 5.0);
    const auto [x, y] = t.take();
    CHECK(x.size() == 22);  // half-pixel columns 0..20, and the last point
    CHECK(x.front() == 0.0);
    CHECK(x.back() == 10.0);
    for (const double v : y) CHECK(v == 5.0);
  }
}

TEST_SUITE("record") {
  /// A 180 deg turn, 30 deg/s^2 up to 30 deg/s and down, sampled every
  /// 10 ms; each sample dated by `date` from its true time.
  std::vector<est::AngleSample> turn(double rate_dps, const std::function<double(double)>& date) {
    constexpr double kDeg = 0.017453292519943295;
    const double a = 30 * kDeg, angle = 180 * kDeg;
    const double w = std::min(rate_dps * kDeg, std::sqrt(a * angle));  // a triangle at most
    const double ramp = w / a, plateau = (angle - w * ramp) / w;
    auto psi = [&](double t) {
      if (t <= 0) return 0.0;
      if (t < ramp) return a * t * t / 2;
      if (t < ramp + plateau) return a * ramp * ramp / 2 + w * (t - ramp);
      const double d = std::min(t - ramp - plateau, ramp);
      return a * ramp * ramp / 2 + w * plateau + w * d - a * d * d / 2;
    };
    std::vector<est::AngleSample> enc;
    for (int k = -20; k <= 800; ++k) {
      const double t = 0.01 * k;
      enc.push_back({date(t), psi(t)});
    }
    return enc;
  }

  TEST_CASE(
      "a turn's peak rate: a fit over 0.2 s, not two samples, so a table timed by its "
      "receipt reads it right") {
    constexpr double kDeg = 0.017453292519943295;
    SUBCASE("samples on their true times: the plateau's rate") {
      const auto enc = turn(30, [](double t) { return t; });
      CHECK(peak_rate_rps(enc, 0, enc.size() - 1) == doctest::Approx(30 * kDeg).epsilon(1e-9));
    }
    SUBCASE("samples dated by their receipt after 25 ms stalls: within 5% of the plateau") {
      // every 0.5 s the host reads nothing for 25 ms, then the waiting
      // samples at once: the last of them and the next read 10 ms apart
      // span 13.5 ms of the turn. Two-sample slopes over 10 ms read 1.35
      // times the plateau here; a fit over 0.1 s, 1.11 times
      const auto enc = turn(30, [](double t) {
        const double phase = std::fmod(t + 1, 0.5);
        if (phase < 0.3 - 1e-9 || phase >= 0.325 - 1e-9) return t;
        return t - phase + 0.325 + 1e-4 * std::round((phase - 0.3) / 0.01);
      });
      const double peak = peak_rate_rps(enc, 0, enc.size() - 1);
      CHECK(peak / (30 * kDeg) - 1 < 0.05);
      CHECK(peak / (30 * kDeg) - 1 > 0);
    }
    SUBCASE("a turn with no plateau (180 deg never reaching 200 deg/s): 3 alpha 0.2 s / 16 low") {
      // peak of a triangle: sqrt(alpha * angle) = 73.5 deg/s at 30 deg/s^2
      const auto enc = turn(200, [](double t) { return t; });
      const double vertex = std::sqrt(30 * 180.0) * kDeg;
      const double peak = peak_rate_rps(enc, 0, enc.size() - 1);
      CHECK(peak < vertex);
      // 3 alpha W / 16 in the continuum; the 10 ms samples add 5% to it
      const double shortfall = 3 * 30 * kDeg * kPeakWindowS / 16;
      CHECK(vertex - peak > shortfall * 0.95);
      CHECK(vertex - peak < shortfall * 1.1);
    }
    SUBCASE("a motion shorter than the window: one fit over all of it") {
      std::vector<est::AngleSample> enc;
      for (int k = 0; k <= 5; ++k) enc.push_back({0.01 * k, 0.002 * k});
      CHECK(peak_rate_rps(enc, 0, enc.size() - 1) == doctest::Approx(0.2).epsilon(1e-9));
    }
  }
}
