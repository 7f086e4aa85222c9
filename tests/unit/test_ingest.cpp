// Frames into samples: unwrapping, clock fits, health, bad frames counted.
#include <doctest/doctest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <numbers>
#include <random>
#include <sstream>

#include "turncal/build_paths.hpp"
#include "turncal/drivers/reference.hpp"
#include "turncal/run/engine.hpp"
#include "turncal/run/ingest.hpp"
#include "turncal/run/sequencer.hpp"

using namespace turncal;
using namespace turncal::run;

namespace {

struct Ref {
  Config cfg;
  can::Database db;
  RoleMap roles;
  Ref() {
    auto c = parse_config("", std::string(turncal::build::source_dir) + "/config/turncal.toml");
    REQUIRE(c.ok());
    cfg = *c;
    auto d = load_databases(cfg.can);
    REQUIRE(d.ok());
    db = std::move(*d);
    auto r = resolve_roles(cfg.can, db);
    REQUIRE(r.ok());
    roles = *r;
  }
  can::TimedFrame at(double t, can::Frame f) const {
    return {static_cast<std::int64_t>(std::llround(t * 1e9)), f};
  }
  can::TimedFrame vel(double t, bool east, double tag_us, double v) const {
    return at(t, east ? roles.encode(Role::InsVelEast,
                                     {{Role::InsVelEast, v}, {Role::InsVelEastTimeTag, tag_us}})
                      : roles.encode(Role::InsVelNorth,
                                     {{Role::InsVelNorth, v}, {Role::InsVelNorthTimeTag, tag_us}}));
  }
};

}  // namespace

TEST_SUITE("ingest") {
  TEST_CASE("time tags unwrap across the u32 range; a late frame stays before the wrap") {
    TagUnwrap u;
    CHECK(u(4294967000.0) == doctest::Approx(4294.967));
    CHECK(u(100.0) == doctest::Approx(4294.967396));       // wrapped
    CHECK(u(4294967200.0) == doctest::Approx(4294.9672));  // late, from before the wrap
    CHECK(u(300.0) == doctest::Approx(4294.967596));
  }

  TEST_CASE("angles unwrap into multi-turn, each step the short way") {
    AngleUnwrap u;
    const double d = std::numbers::pi / 180;
    CHECK(u(350 * d) == doctest::Approx(350 * d));
    CHECK(u(10 * d) == doctest::Approx(370 * d));
    CHECK(u(355 * d) == doctest::Approx(355 * d));
  }

  TEST_CASE("clock fit recovers offset and rate; outliers are kept out") {
    ClockFit f;
    for (int k = 0; k < 2000; ++k) {  // 20 s: the gate applies after 10
      const double host = 1.7e9 + 0.01 * k;
      const double dev = 1000 + (host - 1.7e9) * (1 + 50e-6);
      const double latency = (k % 7) * 1e-5;  // receive latency, over a floor of 0
      CHECK(f.add_checked(dev, host + latency));
    }
    CHECK(f.rate_ppm() == doctest::Approx(50).epsilon(0.001));
    // the envelope is the send time: the latency floor, not its mean (a
    // double at 1.7e9 s resolves 0.24 us)
    CHECK(std::abs(f.to_host(1000 + 5 * (1 + 50e-6)) - (1.7e9 + 5)) < 3e-7);
    CHECK(std::abs(f.to_device(f.to_host(1003)) - 1003) < 3e-7);
    CHECK_FALSE(f.add_checked(1000 + 10.5, 1.7e9 + 10.3));  // 0.2 s early: the clock jumped
    CHECK(f.count() == 2000);
    CHECK(f.late() == 0);
    CHECK(f.add_checked(1000 + 10.5, 1.7e9 + 10.7));  // 0.2 s late: added, counted late
    CHECK(f.late() == 1);
  }

  TEST_CASE("clock fit: delays, however long and early, leave the line where it was") {
    // A device 30 ppm slow against a host that stalls: every second, a
    // stall of 20 to 300 ms holds back the frames in it, which then arrive
    // at its end in a burst; the first stall comes in the first second. A
    // mean through the samples would sit tens of ms late and tilt with
    // where the stalls fell (the failure this replaced: an early stall
    // tilted it 12%, and its gate then shut out every later sample).
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> u(0, 1);
    ClockFit f;
    const double rate = -30e-6;
    double stall_from = 0.2, stall_to = 0.2 + 0.3;
    int frames = 0;
    for (int k = 0; k < 25 * 600; ++k) {  // 25 Hz for 10 minutes
      const double send = 0.04 * k;
      if (send > stall_to) {
        stall_from = std::floor(send) + 1 + u(rng) * 0.5;
        stall_to = stall_from + 0.02 + 0.28 * u(rng);
      }
      double host = send + 0.0002 + 0.0003 * u(rng);  // the latency floor and scatter
      if (send >= stall_from && send < stall_to) host = stall_to + 0.0001 * (send - stall_from);
      const double dev = 500 + send * (1 + rate);
      CHECK(f.add_checked(dev, 1.8e9 + host));
      ++frames;
    }
    CHECK(f.count() == static_cast<std::size_t>(frames));
    CHECK(f.rate_ppm() == doctest::Approx(-30).epsilon(0.05));  // within 1.5 ppm
    // the floor, 0.2 ms, within the scatter of the fastest frames
    for (double t : {1.0, 300.0, 599.0}) {
      CAPTURE(t);
      const double err = f.to_host(500 + t * (1 + rate)) - (1.8e9 + t);
      CHECK(err > 0.0001);
      CHECK(err < 0.0003);
    }
    CHECK(f.late() > 100);  // the stalls, seen
  }

  TEST_CASE("velocity pairs by tag; half pairs count as drops; malformed and unknown counted") {
    Ref r;
    Ingest in(r.db, r.roles);
    int samples = 0;
    for (int k = 0; k < 100; ++k) {
      const double t = 10 + 0.01 * k, tag = 1e6 + 1e4 * k;
      if (k == 50) {
        in.on_frame(r.vel(t, true, tag, 0.001));  // its North half lost
        continue;
      }
      in.on_frame(r.vel(t, true, tag, 0.001));
      const Sample s = in.on_frame(r.vel(t + 1e-4, false, tag, -0.002));
      if (const auto* v = std::get_if<VelocitySample>(&s)) {
        ++samples;
        CHECK(v->ve == doctest::Approx(0.001));
        CHECK(v->vn == doctest::Approx(-0.002));
      }
    }
    CHECK(samples == 99);
    CHECK(in.health(kVelocity).nominal_hz == doctest::Approx(100));
    CHECK(in.health(kVelocity).dropped == 1);
    CHECK(in.counters().half_pairs == 1);
    // a known ID with a wrong length, and an unknown ID
    can::Frame bad = r.roles.encode(Role::EncoderAngle, {});
    bad.len = 3;
    CHECK(std::holds_alternative<std::monostate>(in.on_frame(r.at(11, bad))));
    can::Frame unknown = bad;
    unknown.id = 0x7ff;
    in.on_frame(r.at(11, unknown));
    CHECK(in.counters().malformed == 1);
    CHECK(in.counters().unknown_id == 1);
    // stale after 10 periods unseen
    CHECK_FALSE(in.health(kVelocity).stale(11.05));
    CHECK(in.health(kVelocity).stale(11.2));
    CHECK(in.health(kEncoder).stale(11));  // never seen
    // and never before the floor, when one is set
    CHECK_FALSE(in.health(kVelocity).stale(11.2, 0.3));
    CHECK(in.health(kVelocity).stale(11.35, 0.3));
  }

  TEST_CASE("implausible values are counted and skipped: the velocity bound, the DBC range") {
    Ref r;
    Plausibility p;
    p.max_velocity_mps = 100;
    Ingest in(r.db, r.roles, p);
    auto pair = [&](int k, double ve) {
      const double t = 10 + 0.01 * k, tag = 1e6 + 1e4 * k;
      in.on_frame(r.vel(t, true, tag, ve));
      return in.on_frame(r.vel(t + 1e-4, false, tag, 0.0));
    };
    CHECK(std::holds_alternative<VelocitySample>(pair(0, 99.0)));  // under the bound
    CHECK(std::holds_alternative<std::monostate>(pair(1, 150.0)));
    CHECK(std::holds_alternative<std::monostate>(pair(2, -150.0)));
    CHECK(std::holds_alternative<VelocitySample>(pair(3, 0.001)));
    CHECK(in.health(kVelocity).implausible == 2);
    CHECK(in.health(kVelocity).frames == 4);  // the two pairs and the two East halves skipped
    // the DBC's range, where it gives one
    Ref ranged;
    for (can::Message& m : ranged.db.messages)
      for (can::Signal& sig : m.signals)
        if (m.name == "INS_VelE" && sig.name == "VelE") {
          sig.minimum = -10;
          sig.maximum = 10;
        }
    Ingest in2(ranged.db, ranged.roles, p);
    const double tag = 2e6;
    in2.on_frame(ranged.vel(20, true, tag, 11.0));
    CHECK(std::holds_alternative<std::monostate>(in2.on_frame(ranged.vel(20, false, tag, 0.0))));
    CHECK(in2.health(kVelocity).implausible == 1);
    in2.on_frame(ranged.vel(20.01, true, tag + 1e4, 9.5));
    CHECK(std::holds_alternative<VelocitySample>(
        in2.on_frame(ranged.vel(20.01, false, tag + 1e4, 0.0))));
    // [0|0] is no range, as vendor files write it: 50 m/s passes
    Ref none;
    for (can::Message& m : none.db.messages)
      for (can::Signal& sig : m.signals)
        if (m.name == "INS_VelE" && sig.name == "VelE") sig.minimum = sig.maximum = 0;
    Ingest in3(none.db, none.roles, p);
    in3.on_frame(none.vel(20, true, tag, 50.0));
    CHECK(std::holds_alternative<VelocitySample>(in3.on_frame(none.vel(20, false, tag, 0.0))));
    CHECK(in3.health(kVelocity).implausible == 0);
    // no checks (the replay of a run recorded before turncal checked
    // frames): the bound and the DBC's range both pass
    Ingest in4(ranged.db, ranged.roles, Plausibility::none());
    in4.on_frame(ranged.vel(30, true, tag, 150.0));
    CHECK(std::holds_alternative<VelocitySample>(in4.on_frame(ranged.vel(30, false, tag, 0.0))));
    CHECK(in4.health(kVelocity).implausible == 0);
  }

  /// The reference table, its encoder samples timed by their receive time
  /// (a fake seam: a CiA 402 drive's TPDO without SYNC has no clock of its
  /// own either).
  class ReceiveTimed : public TableDriver {
   public:
    explicit ReceiveTimed(std::unique_ptr<TableDriver> t) : t_(std::move(t)) {}
    Decoded decode(const FrameView& v) override {
      Decoded d = t_->decode(v);
      if (d.verdict == Decoded::Verdict::Taken && d.stream == kEncoder) d.device_s = v.host_s;
      return d;
    }
    void accept_encoder() override { t_->accept_encoder(); }
    [[nodiscard]] double angle_resolution_rad() const override {
      return t_->angle_resolution_rad();
    }
    Result<std::vector<can::Frame>> command(const TableCommand& c) override {
      return t_->command(c);
    }
    [[nodiscard]] std::vector<can::Frame> heartbeat(std::uint8_t c, int s) const override {
      return t_->heartbeat(c, s);
    }
    [[nodiscard]] SignalSpan target() const override { return t_->target(); }
    [[nodiscard]] SignalSpan rate_limit() const override { return t_->rate_limit(); }
    [[nodiscard]] std::vector<std::pair<std::uint32_t, bool>> receive_ids() const override {
      return t_->receive_ids();
    }

   private:
    std::unique_ptr<TableDriver> t_;
  };

  TEST_CASE("a role past the 64th signal of a wide CAN FD message is decoded, not read past") {
    // the reference stand's encoder in a 64-byte frame, its time tag and
    // angle the 69th and 70th of its signals: the decode buffer holds the
    // widest message's signals (it held 64)
    Ref r;
    std::ifstream in_dbc(std::string(turncal::build::source_dir) + "/config/reference-stand.dbc");
    std::stringstream text;
    text << in_dbc.rdbuf();
    std::string dbc = text.str();
    const std::string enc =
        "BO_ 513 TBL_Encoder: 8 TBL\n"
        " SG_ TimeTag : 0|32@1+ (1,0) [0|4294967295] \"us\" HOST\n"
        " SG_ Angle : 32|32@1+ (8.381903171539306640625E-008,0) [0|360] \"deg\" HOST\n";
    REQUIRE(dbc.find(enc) != std::string::npos);
    std::string wide = "BO_ 513 TBL_Encoder: 64 TBL\n";
    for (int i = 0; i < 68; ++i)
      wide += " SG_ Pad" + std::to_string(i) + " : " + std::to_string(4 * i) +
              "|4@1+ (1,0) [0|15] \"\" HOST\n";
    wide +=
        " SG_ TimeTag : 272|32@1+ (1,0) [0|4294967295] \"us\" HOST\n"
        " SG_ Angle : 304|32@1+ (8.381903171539306640625E-008,0) [0|360] \"deg\" HOST\n";
    dbc.replace(dbc.find(enc), enc.size(), wide);
    const std::string path = "/tmp/turncal-unit-wide-" + std::to_string(::getpid()) + ".dbc";
    std::ofstream(path) << dbc;
    Config cfg = r.cfg;
    cfg.can.dbc_files = {path};
    cfg.can.fd = true;
    auto d = load_databases(cfg.can);
    std::remove(path.c_str());
    REQUIRE(d.ok());
    const can::Database db = std::move(*d);
    auto ro = resolve_roles(cfg.can, db);
    REQUIRE(ro.ok());
    const RoleMap roles = *ro;
    const can::Frame probe = roles.encode(Role::EncoderAngle, {});
    REQUIRE(probe.len == 64);
    REQUIRE(can::FrameCodec(db).max_signals() == 70);
    Ingest in(db, roles);
    int kept = 0;
    for (int k = 0; k < 20; ++k) {
      const double deg = 10.0 + 0.5 * k;
      const can::Frame f = roles.encode(
          Role::EncoderAngle, {{Role::EncoderAngle, deg}, {Role::EncoderTimeTag, 1e6 + 4e4 * k}});
      const Sample smp = in.on_frame(r.at(10 + 0.04 * k, f));
      if (const auto* e = std::get_if<EncoderSample>(&smp)) {
        ++kept;
        CHECK(e->angle_rad * 180 / std::numbers::pi == doctest::Approx(deg).epsilon(1e-7));
        CHECK(e->t_table_s == doctest::Approx(1 + 0.04 * k).epsilon(1e-12));
      }
    }
    CHECK(kept == 20);
    CHECK(in.counters().malformed == 0);
  }

  TEST_CASE("an encoder timed by its receive time: frames read in a burst count no drops") {
    Ref r;
    Ingest in(r.db, drivers::make_reference_ins(r.roles, {}),
              std::make_unique<ReceiveTimed>(drivers::make_reference_table(r.roles, {})));
    auto enc = [&](double host, int k) {
      return in.on_frame(
          r.at(host, r.roles.encode(Role::EncoderAngle, {{Role::EncoderAngle, 0.0},
                                                         {Role::EncoderTimeTag, 1e6 + 4e4 * k}})));
    };
    // 25 Hz, the 11th frame read 0.1 ms after the 10th (the host was late)
    int kept = 0;
    for (int k = 0; k < 100; ++k)
      kept +=
          std::holds_alternative<EncoderSample>(enc(10 + 0.04 * k + (k == 10 ? -0.0399 : 0), k));
    CHECK(kept == 100);
    // timed by the receive time, a gap is no drop: the period a burst
    // showed would make every later interval hundreds of "lost" frames
    CHECK(in.health(kEncoder).dropped == 0);
    CHECK(in.health(kEncoder).nominal_hz == doctest::Approx(in.health(kEncoder).rate_hz()));
    CHECK(in.health(kEncoder).nominal_hz > 24);
    CHECK(in.health(kEncoder).nominal_hz < 26);
  }

  /// The reference table, each encoder sample carrying a loss count of the
  /// device's own (a fake seam: a CiA 402 TPDO1 answering our SYNC), from
  /// `lost` by the sample's index.
  class DeviceCounted : public ReceiveTimed {
   public:
    DeviceCounted(std::unique_ptr<TableDriver> t, std::function<std::int64_t(int)> lost)
        : ReceiveTimed(std::move(t)), lost_(std::move(lost)) {}
    Decoded decode(const FrameView& v) override {
      Decoded d = ReceiveTimed::decode(v);
      if (d.verdict != Decoded::Verdict::Taken || d.stream != kEncoder) return d;
      d.device_s = std::get<EncoderSample>(d.sample).t_table_s;  // the tag, as a SYNC's time
      d.lost_before = lost_(k_++);
      return d;
    }

   private:
    std::function<std::int64_t(int)> lost_;
    int k_ = 0;
  };

  TEST_CASE("an encoder that counts its own losses: its count, not the gaps; a restart none") {
    Ref r;
    Plausibility p;
    p.max_table_rate_rps = 60 * std::numbers::pi / 180;
    // 100 Hz; two lost before sample 30 (its gap three periods), a stream
    // restarted 3 s later at 50 (no loss), one lost before sample 70, which
    // is itself refused (an angle 90 deg off)
    auto lost = [](int k) -> std::int64_t {
      if (k == 0 || k == 50) return kStreamRestarted;
      if (k == 30) return 2;
      if (k == 70) return 1;
      return 0;
    };
    Ingest in(r.db, drivers::make_reference_ins(r.roles, {}),
              std::make_unique<DeviceCounted>(drivers::make_reference_table(r.roles, {}), lost), p);
    double t = 10;
    int kept = 0;
    for (int k = 0; k < 100; ++k) {
      t += k == 30 || k == 70 ? 0.01 * (1 + static_cast<double>(lost(k))) : k == 50 ? 3.0 : 0.01;
      const double deg = k == 70 ? 90.0 : 0.0;
      const Sample s = in.on_frame(r.at(
          t, r.roles.encode(Role::EncoderAngle,
                            {{Role::EncoderAngle, deg}, {Role::EncoderTimeTag, (t - 5) * 1e6}})));
      kept += std::holds_alternative<EncoderSample>(s);
    }
    const StreamHealth& h = in.health(kEncoder);
    CHECK(kept == 99);
    CHECK(h.implausible == 1);
    // the device's three, counted also for the refused sample; the 3 s of
    // the restart none (by the gaps: 2 + 299)
    CHECK(h.dropped == 3);
    // the mean rate while it ran, the losses in, the restart out: 100 Hz
    // (the refused sample's interval and loss count: it was received)
    CHECK(h.nominal_hz == doctest::Approx(100).epsilon(1e-6));
  }

  TEST_CASE("an encoder step faster than the table can turn is skipped, and turns nothing") {
    Ref r;
    Plausibility p;
    p.max_table_rate_rps = 60 * std::numbers::pi / 180;
    Ingest in(r.db, r.roles, p);
    auto enc = [&](int k, double deg) {
      return in.on_frame(
          r.at(10 + 0.005 * k,
               r.roles.encode(Role::EncoderAngle,
                              {{Role::EncoderAngle, deg}, {Role::EncoderTimeTag, 1e6 + 5e3 * k}})));
    };
    double last = NAN;
    int kept = 0;
    for (int k = 0; k < 100; ++k) {
      // 30 deg/s, across 0/360; at k = 40 and 41 a garbled angle 90 deg off
      const double deg = std::fmod(350 + 0.15 * k + (k == 40 || k == 41 ? 90 : 0), 360);
      const Sample s = enc(k, deg);
      if (const auto* e = std::get_if<EncoderSample>(&s)) {
        ++kept;
        last = e->angle_rad;
      }
    }
    CHECK(kept == 98);
    CHECK(in.health(kEncoder).implausible == 2);
    // the multi-turn angle goes on from before the garble: 350 + 14.85 deg
    CHECK(last * 180 / std::numbers::pi == doctest::Approx(364.85).epsilon(1e-9));
  }

  TEST_CASE("the encoder step is judged on host time: a garbled tag, a garbled first sample") {
    Ref r;
    Plausibility p;
    p.max_table_rate_rps = 60 * std::numbers::pi / 180;
    p.step_slack_s = 0.05;
    // host time, device tag and angle of each frame (the angle signal's
    // resolution is 8.4e-8 deg: a relative 1e-7 is a few counts)
    auto run = [&](Ingest& in, double host, double tag_s, double deg) {
      const Sample s = in.on_frame(r.at(
          host, r.roles.encode(Role::EncoderAngle,
                               {{Role::EncoderAngle, deg}, {Role::EncoderTimeTag, tag_s * 1e6}})));
      const auto* e = std::get_if<EncoderSample>(&s);
      return e == nullptr ? std::numeric_limits<double>::quiet_NaN()
                          : e->angle_rad * 180 / std::numbers::pi;
    };
    SUBCASE("a tag garbled far ahead does not open the door to a garbled angle") {
      Ingest in(r.db, r.roles, p);
      for (int k = 0; k < 10; ++k) CHECK(run(in, 10 + 0.005 * k, 1 + 0.005 * k, 10 + 0.1 * k) > 0);
      (void)run(in, 10.050, 1000, 11.0);                 // the tag 1000 s ahead
      CHECK(std::isnan(run(in, 10.055, 1.055, 100.0)));  // 89 deg in 5 ms: refused
      CHECK(run(in, 10.060, 1.060, 11.2) == doctest::Approx(11.2).epsilon(1e-7).scale(0));
      CHECK(in.health(kEncoder).implausible == 1);
    }
    SUBCASE("frames that queued arrive together: steps of their period, no host time") {
      Ingest in(r.db, r.roles, p);
      // 50 deg/s (under the 60 deg/s allowed), 10 frames in one host instant
      int kept = 0;
      for (int k = 0; k < 10; ++k) kept += run(in, 20.0, 1 + 0.005 * k, 0.25 * k) >= 0;
      CHECK(kept == 10);
      CHECK(in.health(kEncoder).implausible == 0);
    }
    SUBCASE("a garbled first sample: the samples after it agree, and replace it") {
      Ingest in(r.db, r.roles, p);
      CHECK(run(in, 10.000, 1.000, 95.0) ==
            doctest::Approx(95.0).epsilon(1e-7).scale(0));  // 90 off
      CHECK(std::isnan(run(in, 10.005, 1.005, 5.05)));
      CHECK(std::isnan(run(in, 10.010, 1.010, 5.10)));
      CHECK(run(in, 10.015, 1.015, 5.15) ==
            doctest::Approx(5.15).epsilon(1e-7).scale(0));  // the third
      CHECK(run(in, 10.020, 1.020, 5.20) == doctest::Approx(5.20).epsilon(1e-7).scale(0));
      CHECK(in.health(kEncoder).implausible == 2);
      CHECK(in.counters().encoder_reanchored == 1);
    }
    SUBCASE("later in the stream, agreeing samples off the reference stay refused") {
      Ingest in(r.db, r.roles, p);
      for (int k = 0; k < 20; ++k) CHECK(run(in, 10 + 0.005 * k, 1 + 0.005 * k, 5.0) >= 0);
      // a stuck offset of 90 deg: consistent, and wrong
      for (int k = 20; k < 30; ++k) CHECK(std::isnan(run(in, 10 + 0.005 * k, 1 + 0.005 * k, 95.0)));
      CHECK(in.counters().encoder_reanchored == 0);
      CHECK(in.health(kEncoder).implausible == 10);
    }
    SUBCASE("refused samples that disagree with each other never replace the reference") {
      Ingest in(r.db, r.roles, p);
      CHECK(run(in, 10.000, 1.000, 5.0) >= 0);
      for (int k = 1; k <= 6; ++k)
        CHECK(std::isnan(run(in, 10 + 0.005 * k, 1 + 0.005 * k, 5.0 + 40.0 * k)));
      CHECK(in.counters().encoder_reanchored == 0);
      CHECK(run(in, 10.040, 1.040, 5.4) == doctest::Approx(5.4).epsilon(1e-7).scale(0));
    }
  }

  TEST_CASE("table status carries the fault's name from the DBC's value table") {
    Ref r;
    Ingest in(r.db, r.roles);
    const Sample s = in.on_frame(
        r.at(1, r.roles.encode(Role::TableState, {{Role::TableState, 4}, {Role::TableFault, 2}})));
    const auto* st = std::get_if<TableStatusSample>(&s);
    REQUIRE(st != nullptr);
    CHECK(st->state == 4);
    CHECK(st->fault_name == "stall");
  }
}

TEST_SUITE("sequencer") {
  TEST_CASE("the plan is checked against the limits before any command") {
    SequencerSettings s;
    s.profile = classic_profile(600, 300, std::numbers::pi, 0.5, 0.5);
    CHECK(check_plan(s).empty());
    s.limits.angle_max_rad = 1.0;
    CHECK(check_plan(s).find("turn 1: end angle 180.000 deg is outside") == 0);
    s.limits.angle_max_rad = 10;
    s.limits.max_accel_rps2 = 0.4;
    CHECK(check_plan(s).find("turn 1: acceleration") == 0);
  }

  TEST_CASE("a start with the table unheard: no enable sent blind, a fault after the grace") {
    SequencerSettings s;
    s.profile = classic_profile(600, 300, std::numbers::pi, 0.5, 0.5);
    Sequencer q(s);
    std::vector<Command> out;
    q.step(StartRequest{1}, out);
    CHECK(out.empty());
    Tick quiet{1.5};
    quiet.table_status_stale = true;
    q.step(quiet, out);  // within the grace: not yet lost
    CHECK(out.empty());
    CHECK(q.phase() == Phase::Prepare);
    quiet.t_s = 2.1;
    q.step(quiet, out);
    CHECK(q.course().reason == "the table not heard: no TBL_Status since the start of the run");
    // the table may be there and deaf to us: it is told to stop all the
    // same, once; it was sent nothing else, so the run ends there (no
    // quick stop to wait for, nothing that would hold the next start)
    REQUIRE(out.size() == 1);
    CHECK(std::get<TableCommand>(out[0]).code == TableCode::QuickStop);
    CHECK(q.phase() == Phase::Failed);
    CHECK(q.host_state() == 0);
    CHECK_FALSE(q.course().quick_stop_gave_up);
  }

  TEST_CASE("the table's first status in fault or moving: no enable, the run fails") {
    for (const int state : {4, 2}) {
      CAPTURE(state);
      SequencerSettings s;
      s.profile = classic_profile(600, 300, std::numbers::pi, 0.5, 0.5);
      Sequencer q(s);
      std::vector<Command> out;
      q.step(StartRequest{1}, out);
      q.step(TableStatusEvent{1.05, state, 0, state == 4 ? 2 : 0, state == 4 ? "stall" : "", 0.0},
             out);
      REQUIRE(out.size() == 1);  // a quick stop, never an enable
      CHECK(std::get<TableCommand>(out[0]).code == TableCode::QuickStop);
      CHECK(q.course().reason ==
            (state == 4 ? "table fault: stall, found before the run commanded the table: turncal "
                          "resets no fault whose cause it did not see; reset it at the stand, then "
                          "start again"
                        : "the table is moving before the run commanded it: stop it at the stand"));
    }
  }

  /// A run started and its enable sent (seq 42), for the tests of a table
  /// that starts up first; ticks of it starting up, every 0.1 s from `from`.
  struct Starting {
    Sequencer q{[] {
      SequencerSettings s;
      s.profile = classic_profile(600, 300, std::numbers::pi, 0.5, 0.5);
      s.table_seq_base = 41;
      return s;
    }()};
    std::vector<Command> out;
    Starting() {
      q.step(StartRequest{1}, out);
      q.step(TableStatusEvent{1.05, 0, 41, 0, "", 0.0}, out);
    }
    void starting_up(double from, double to) {
      Tick k{0};
      k.table_starting = true;
      for (double at = from; at < to; at += 0.1) {
        k.t_s = at;
        q.step(k, out);
      }
    }
  };

  TEST_CASE("a table protocol still starting up: the enable's ack is due from when it is up") {
    Starting st;
    Sequencer& q = st.q;
    std::vector<Command>& out = st.out;
    REQUIRE(out.size() == 1);
    CHECK(std::get<TableCommand>(out[0]).code == TableCode::Enable);
    // starting (a CANopen configuration) for 3 s, far past the 1 s ack timeout
    st.starting_up(1.1, 4.05);
    CHECK(q.phase() != Phase::Failed);
    CHECK(out.size() == 1);  // nothing since the enable
    // up: the 1 s runs from its last tick of starting up, 4.0
    q.step(Tick{4.9}, out);
    CHECK(out.size() == 1);
    q.step(Tick{5.1}, out);
    REQUIRE(out.size() == 2);  // the fault's quick stop
    CHECK(std::get<TableCommand>(out[1]).code == TableCode::QuickStop);
    CHECK(q.course().reason.find("the table did not acknowledge enable within 1000 ms") == 0);
  }

  TEST_CASE(
      "a table protocol still starting up: the enable's 5 s to holding run from when it is up") {
    Starting st;
    Sequencer& q = st.q;
    std::vector<Command>& out = st.out;
    REQUIRE(out.size() == 1);
    q.step(TableStatusEvent{1.1, 0, 42, 0, "", 0.0}, out);  // acknowledged, not yet holding
    st.starting_up(1.2, 8.05);
    CHECK(out.size() == 1);  // 7 s, and no timeout
    q.step(Tick{12.9}, out);
    CHECK(out.size() == 1);
    q.step(Tick{13.1}, out);  // 5 s after the last tick of starting up
    REQUIRE(out.size() == 2);
    CHECK(std::get<TableCommand>(out[1]).code == TableCode::QuickStop);
    CHECK(q.course().reason.find("the table not holding within 5 s of enable") !=
          std::string::npos);
  }

  // The demo failed so (three times of three, in user-mode Linux at 10x):
  // the host's loop read the table's first status 170 ms of real time after
  // the bus had it, the enable went out then, and its 1.5 s (stand) ran from
  // the status's time: past before the table could hear it.
  TEST_CASE("a command's waits run from when it was sent, not from the event read late") {
    Starting st;
    Sequencer& q = st.q;
    std::vector<Command>& out = st.out;
    REQUIRE(out.size() == 1);  // the enable, called for by the status at 1.05
    REQUIRE(std::get<TableCommand>(out[0]).code == TableCode::Enable);
    q.sent(2.8);             // the host sent it 1.75 s later
    q.step(Tick{3.7}, out);  // 2.65 s after the status, 0.9 s after the send
    CHECK(q.phase() == Phase::Prepare);
    CHECK(out.size() == 1);
    q.step(Tick{3.85}, out);  // 1.05 s after the send: the ack's 1 s is past
    REQUIRE(out.size() == 2);
    CHECK(std::get<TableCommand>(out[1]).code == TableCode::QuickStop);
    CHECK(q.course().reason.find("the table did not acknowledge enable within 1000 ms") == 0);
  }

  TEST_CASE("sent() moves only the waits of the commands not yet said sent") {
    Starting st;
    Sequencer& q = st.q;
    std::vector<Command>& out = st.out;
    q.sent(1.05);  // sent at once: nothing moves
    q.sent(2.8);   // said again later: nothing waits any more, nothing moves
    q.step(Tick{2.0}, out);
    CHECK(out.size() == 1);
    q.step(Tick{2.1}, out);  // 1.05 s after the enable
    REQUIRE(out.size() == 2);
    CHECK(std::get<TableCommand>(out[1]).code == TableCode::QuickStop);
    // the quick stop's give-up runs from its send too: sent 1 s late, it
    // gives up 5 s after the send, not after the tick that called for it
    q.sent(3.1);
    for (double at = 2.2; at < 8.05; at += 0.1) q.step(Tick{at}, out);
    CHECK(q.phase() != Phase::Failed);
    q.step(Tick{8.15}, out);
    CHECK(q.phase() == Phase::Failed);
  }

  TEST_CASE("the enable's wait to holding runs from its send too") {
    Starting st;
    Sequencer& q = st.q;
    std::vector<Command>& out = st.out;
    q.sent(3.05);                                           // 2 s late
    q.step(TableStatusEvent{3.1, 0, 42, 0, "", 0.0}, out);  // acknowledged, not holding
    q.step(Tick{7.95}, out);  // 6.9 s after the status that called for it
    CHECK(out.size() == 1);
    q.step(Tick{8.1}, out);  // 5.05 s after the send
    REQUIRE(out.size() == 2);
    CHECK(q.course().reason.find("the table not holding within 5 s of enable") !=
          std::string::npos);
  }

  TEST_CASE("an accelerated stand's real-time floor lengthens every wait, and says so") {
    SequencerSettings s;
    s.profile = classic_profile(600, 300, std::numbers::pi, 0.5, 0.5);
    s.table_seq_base = 41;
    s.stale_floor_s = 0.5;       // 50 ms at 10x
    s.real_time_floor_s = 10.0;  // 1000 ms at 10x
    Sequencer q(s);
    std::vector<Command> out;
    q.step(StartRequest{1}, out);
    q.step(TableStatusEvent{1.05, 0, 41, 0, "", 0.0}, out);
    REQUIRE(out.size() == 1);
    q.step(Tick{12.5}, out);  // 11.45 s: within 1 + 0.5 + 10
    CHECK(out.size() == 1);
    q.step(Tick{12.6}, out);
    REQUIRE(out.size() == 2);
    CHECK(q.course().reason.find("the table did not acknowledge enable within 11500 ms") == 0);
    // the quick stop's give-up: 5 s and the floor
    for (double at = 12.7; at < 27.55; at += 0.25) q.step(Tick{at}, out);
    CHECK(q.phase() != Phase::Failed);
    q.step(Tick{27.7}, out);
    CHECK(q.phase() == Phase::Failed);
    CHECK(q.course().reason.find("THE TABLE DID NOT REPORT STOPPED within 15.0 s") !=
          std::string::npos);
  }

  TEST_CASE("the real-time floor: none at a time scale of 1, N times the floor at N") {
    StandConfig stand;
    stand.real_time_floor_ms = 1000;
    stand.time_scale = 1;
    CHECK(real_time_floor_s(stand) == 0);
    stand.time_scale = 0.5;
    CHECK(real_time_floor_s(stand) == 0);
    stand.time_scale = 10;
    CHECK(real_time_floor_s(stand) == doctest::Approx(10.0).epsilon(1e-12));
    stand.real_time_floor_ms = 250;
    stand.time_scale = 4;
    CHECK(real_time_floor_s(stand) == doctest::Approx(1.0).epsilon(1e-12));
  }

  TEST_CASE("idle: a signal or an abort changes nothing; a start enables the table") {
    SequencerSettings s;
    s.profile = classic_profile(600, 300, std::numbers::pi, 0.5, 0.5);
    s.table_seq_base = 41;
    Sequencer q(s);
    std::vector<Command> out;
    q.step(SignalEvent{0, "SIGTERM"}, out);
    q.step(AbortRequest{0, ""}, out);
    CHECK(q.phase() == Phase::Idle);
    CHECK(out.empty());
    q.step(StartRequest{1}, out);
    CHECK(out.empty());  // enable goes with the table's first status
    q.step(TableStatusEvent{1.05, 0, 41, 0, "", 0.0}, out);
    REQUIRE(out.size() == 1);
    const auto& t = std::get<TableCommand>(out[0]);
    CHECK(t.code == TableCode::Enable);
    CHECK(t.seq == 42);  // on from the base: never an old acknowledgement
    // the table never answers: a fault after the ack timeout, and a quick stop
    out.clear();
    q.step(Tick{2.5}, out);
    REQUIRE(out.size() == 1);
    CHECK(std::get<TableCommand>(out[0]).code == TableCode::QuickStop);
    // unanswered, the quick stop goes again every 0.25 s, a new sequence
    // number each time, until 5 s have passed
    out.clear();
    q.step(Tick{2.6}, out);
    CHECK(out.empty());
    q.step(Tick{2.75}, out);
    REQUIRE(out.size() == 1);
    CHECK(std::get<TableCommand>(out[0]).code == TableCode::QuickStop);
    CHECK(std::get<TableCommand>(out[0]).seq == 44);
    for (double at = 3; at < 7.5; at += 0.25) q.step(Tick{at}, out);
    CHECK(q.phase() != Phase::Failed);
    CHECK(q.host_state() == 2);  // still stopping
    q.step(Tick{7.6}, out);
    CHECK(q.phase() == Phase::Failed);
    CHECK(q.course().reason.find("the table did not acknowledge enable within 1000 ms") == 0);
    CHECK(q.course().reason.find("THE TABLE DID NOT REPORT STOPPED within 5.0 s") !=
          std::string::npos);
    CHECK(q.course().quick_stops_sent == 20);
    CHECK(q.course().reason.find("sent 20 times") != std::string::npos);
  }

  TEST_CASE("a quick stop is done when the table says it stopped, not when it acknowledged") {
    SequencerSettings s;
    s.profile = classic_profile(600, 300, std::numbers::pi, 0.5, 0.5);
    s.table_seq_base = 41;
    Sequencer q(s);
    std::vector<Command> out;
    q.step(StartRequest{1}, out);
    q.step(TableStatusEvent{1.05, 0, 41, 0, "", 0.0}, out);  // enable, 42, never acknowledged
    out.clear();
    q.step(Tick{2.5}, out);  // the quick stop, 43
    REQUIRE(out.size() == 1);
    const std::uint8_t stop = std::get<TableCommand>(out[0]).seq;
    CHECK(stop == 43);
    // acknowledged, but still moving: not stopped
    q.step(TableStatusEvent{2.55, 2, stop, 0, "", 0.3}, out);
    CHECK(q.host_state() == 2);
    // quick-stopped, but its rate not yet at rest: decelerating
    q.step(TableStatusEvent{2.60, 5, stop, 0, "", 0.05}, out);
    CHECK(q.host_state() == 2);
    CHECK_FALSE(q.course().quick_stop_acked);
    CHECK(q.phase() != Phase::Failed);
    // quick-stopped, its rate not known (its position data quiet): not stopped
    q.step(TableStatusEvent{2.62, 5, stop, 0, "", std::nan("")}, out);
    CHECK_FALSE(q.course().quick_stop_acked);
    CHECK(q.host_state() == 2);
    // at rest: done
    q.step(TableStatusEvent{2.65, 5, stop, 0, "", 0.0}, out);
    CHECK(q.course().quick_stop_acked);
    CHECK(q.phase() == Phase::Failed);
    CHECK(q.course().quick_stops_sent == 1);
  }
}

#include "turncal/run/report.hpp"

TEST_CASE("sha256: the FIPS 180-4 examples") {
  CHECK(sha256_hex("") == "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  CHECK(sha256_hex("abc") == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  CHECK(sha256_hex("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq") ==
        "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
  CHECK(sha256_hex(std::string(1000, 'a')) ==
        "41edece42d63e8d9bf515a9ba6932e1c20cbc9f5a5d134645adb5db1b9737ea3");
}

TEST_CASE("judge: tolerances in display units; none means pass") {
  const nlohmann::json e = {{"nu0_1", {{"value", 1e-6}, {"sigma", 1e-8}}}};  // rad/s
  CHECK(judge(e, {})["pass"] == true);
  // 1e-6 rad/s = 0.206 deg/h
  auto v = judge(e, {{"nu0_1", 0.3, 0.01}});
  CHECK(v["pass"] == true);
  CHECK(v["checks"][0]["value"].get<double>() == doctest::Approx(0.2063).epsilon(1e-3));
  CHECK(judge(e, {{"nu0_1", 0.2, 0.01}})["pass"] == false);
  CHECK(judge(e, {{"r1", 1, 1}})["checks"][0]["why"] == "not estimated");
}

TEST_CASE("sha256: fed in pieces, and of a file read in pieces, with its line count") {
  // more than the 1 MiB sha256_file reads at a time; a first line as long
  // as puts a line's end on the second read's first byte
  const std::string line = "(1700000000.000000) vcan0 123#DEADBEEF\n";
  const std::size_t first = ((std::size_t{1} << 20) + 1) % line.size();
  REQUIRE(first > 0);
  std::string data = std::string(first - 1, '#') + "\n";
  for (int i = 0; i < 30000; ++i) data += line;
  REQUIRE(data.size() > (std::size_t{1} << 20));
  REQUIRE(data[std::size_t{1} << 20] == '\n');
  const std::string whole = sha256_hex(data);
  for (std::size_t piece : {1U, 63U, 64U, 65U, 4097U}) {
    CAPTURE(piece);
    Sha256 s;
    for (std::size_t i = 0; i < data.size(); i += piece) s.update(data.substr(i, piece));
    CHECK(s.hex() == whole);
  }
  const std::string path = "/tmp/turncal-unit-sha256.log";
  {
    std::FILE* f = std::fopen(path.c_str(), "wb");
    REQUIRE(f != nullptr);
    std::fwrite(data.data(), 1, data.size(), f);
    std::fclose(f);
  }
  auto d = sha256_file(path, CountLines::Yes);
  const auto uncounted = sha256_file(path);  // the digest alone, no count
  std::remove(path.c_str());
  REQUIRE(d.ok());
  CHECK(d->sha256 == whole);
  CHECK(d->lines == 30001);
  REQUIRE(uncounted.ok());
  CHECK(uncounted->sha256 == whole);
  CHECK_FALSE(uncounted->lines.has_value());
  CHECK_FALSE(sha256_file(path).ok());
}

TEST_CASE("sha256_file reads a regular file only, at once, and through a link only when asked") {
  const std::string dir = "/tmp/turncal-unit-sha256-" + std::to_string(::getpid());
  std::error_code gone;
  std::filesystem::remove_all(dir, gone);  // a run before with the same pid
  REQUIRE(::mkdir(dir.c_str(), 0700) == 0);
  const std::string file = dir + "/a.log";
  const std::string link = dir + "/link.log";
  const std::string fifo = dir + "/pipe.log";
  std::ofstream(file, std::ios::binary) << "abc";
  REQUIRE(::symlink(file.c_str(), link.c_str()) == 0);
  REQUIRE(::mkfifo(fifo.c_str(), 0600) == 0);
  const auto followed = sha256_file(link);
  const auto refused = sha256_file(link, CountLines::No, Links::Refuse);
  const auto direct = sha256_file(file, CountLines::Yes, Links::Refuse);
  // a FIFO with no writer: a blocking open would never return
  const auto piped = sha256_file(fifo);
  std::remove(fifo.c_str());
  std::remove(link.c_str());
  std::remove(file.c_str());
  ::rmdir(dir.c_str());
  const std::string abc = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad";
  REQUIRE(followed.ok());
  CHECK(followed->sha256 == abc);
  REQUIRE(direct.ok());
  CHECK(direct->sha256 == abc);
  CHECK(direct->lines == 0);
  REQUIRE_FALSE(refused.ok());
  CHECK(refused.error().describe() == "cannot read " + link + ": " + std::strerror(ELOOP));
  REQUIRE_FALSE(piped.ok());
  CHECK(piped.error().describe() == "cannot read " + fifo + ": not a regular file");
}

TEST_CASE("sha256: the SHA extensions' compression and the portable one agree") {
  using turncal::run::detail::sha256_blocks_hardware;
  using turncal::run::detail::sha256_blocks_portable;
  // the portable one alone, on FIPS 180-4's one-block example ("abc", padded)
  std::array<unsigned char, 64> abc{'a', 'b', 'c', 0x80};
  abc[63] = 24;  // its length in bits
  std::array<std::uint32_t, 8> h = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
                                    0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
  const std::array<std::uint32_t, 8> h0 = h;
  sha256_blocks_portable(h, abc.data(), 1);
  CHECK(h == std::array<std::uint32_t, 8>{0xba7816bf, 0x8f01cfea, 0x414140de, 0x5dae2223,
                                          0xb00361a3, 0x96177a9c, 0xb410ff61, 0xf20015ad});
  const auto hw = sha256_blocks_hardware();
  if (hw == nullptr) {
    MESSAGE("this CPU has no SHA extensions: the portable compression only");
    return;
  }
  // both over the same bytes, 1 to 40 blocks at a time from any start state
  std::mt19937 rng(7);
  std::vector<unsigned char> bytes(64 * 40);
  for (unsigned char& b : bytes) b = static_cast<unsigned char>(rng());
  for (std::size_t blocks = 1; blocks <= 40; blocks += 3) {
    CAPTURE(blocks);
    std::array<std::uint32_t, 8> a = h0;
    a[blocks % 8] ^= static_cast<std::uint32_t>(rng());
    std::array<std::uint32_t, 8> b = a;
    sha256_blocks_portable(a, bytes.data(), blocks);
    hw(b, bytes.data(), blocks);
    CHECK(a == b);
  }
  std::array<std::uint32_t, 8> g = h0;
  hw(g, abc.data(), 1);
  CHECK(g == h);
}

TEST_CASE("report text with the truth: the injected value and the error in sigmas") {
  // 1e-6 rad/s = 0.2063 deg/h; df_eff_1 = df0_1 + g g13 at the equator, g = 9.7803 m/s^2
  const nlohmann::json r = {
      {"run_id", "x"},
      {"status", "done"},
      {"site", {{"latitude_rad", 0.0}, {"height_m", 0.0}}},
      {"estimates",
       {{"nu0_1", {{"value", 1.02e-6}, {"sigma", 1e-8}, {"prior_sigma", 1e-5}}},
        {"df_eff_1", {{"value", 2.0e-4}, {"sigma", 1e-5}, {"prior_sigma", 1e-3}}}}},
      {"combinations",
       {{{"lead", "nu0_1"},
         {"coefficients", {{"nu0_1", 1.0}, {"r1", 0.5}}},
         {"value", 1.1e-6},
         {"sigma", 5e-8}}}}};
  const nlohmann::json truth = {
      {"errors", {{"nu0_1", 1e-6}, {"df0_1", 1e-4}, {"g13", 1e-5}, {"r1", 1e-7}}}};
  const std::string plain = report_text(r);
  CHECK(plain.find("truth") == std::string::npos);
  const std::string t = report_text(r, &truth);
  CAPTURE(t);
  CHECK(t.find("error/sigma") != std::string::npos);
  CHECK(t.find("0.206265") != std::string::npos);  // the truth of nu0_1 in deg/h
  CHECK(t.find("+2.00") != std::string::npos);     // (1.02e-6 - 1e-6) / 1e-8
  // df_eff_1 truth 1e-4 + 9.7803e-5 = 1.97803e-4 m/s^2 = 20.17 ug: (2.0e-4 - 1.978e-4) / 1e-5
  CHECK(t.find("+0.22") != std::string::npos);
  // the combination: truth 1e-6 + 0.5e-7 = 1.05e-6, (1.1e-6 - 1.05e-6) / 5e-8 = +1.00
  CHECK(t.find("+1.00 sigma") != std::string::npos);
}
