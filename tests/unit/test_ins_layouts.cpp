// INS output layouts ([ins] and the roles): one frame in navigation axes,
// units and signs, the time from a tag, a time frame or the receipt; and
// the configuration errors that name file, line and key.
#include <doctest/doctest.h>

#include <cmath>
#include <fstream>
#include <memory>
#include <random>
#include <sstream>
#include <string>

#include "turncal/build_paths.hpp"
#include "turncal/drivers/reference.hpp"
#include "turncal/run/ingest.hpp"

using namespace turncal;
using namespace turncal::run;

namespace {

const std::string kStandFile =
    std::string(turncal::build::source_dir) + "/config/stands/navigation-ins/turncal.toml";

std::string stand_text(const std::string& from = "", const std::string& to = "") {
  std::ifstream in(kStandFile);
  std::stringstream s;
  s << in.rdbuf();
  std::string text = s.str();
  if (!from.empty()) {
    const auto at = text.find(from);
    REQUIRE(at != std::string::npos);
    text.replace(at, from.size(), to);
  }
  return text;
}

/// The navigation-ins stand (config/stands), `from` replaced by `to` in its text.
struct Nav {
  Config cfg;
  can::Database db;
  RoleMap roles;
  explicit Nav(const std::string& from = "", const std::string& to = "") {
    auto c = parse_config(stand_text(from, to), kStandFile);
    REQUIRE_MESSAGE(c.ok(), (c.ok() ? "" : c.error().describe()));
    cfg = *c;
    auto d = load_databases(cfg.can);
    REQUIRE(d.ok());
    db = std::move(*d);
    auto r = resolve_roles(cfg.can, db);
    REQUIRE_MESSAGE(r.ok(), (r.ok() ? "" : r.error().describe()));
    roles = *r;
  }
  [[nodiscard]] std::unique_ptr<Ingest> ingest() const {
    drivers::Devices d = drivers::make_devices(cfg.can, roles, Plausibility{}, 1);
    return std::make_unique<Ingest>(db, std::move(d.ins), std::move(d.table));
  }
  static can::TimedFrame at(double t, const can::Frame& f) {
    return {static_cast<std::int64_t>(std::llround(t * 1e9)), f};
  }
  /// INS_NavVel: North and West, cm/s.
  [[nodiscard]] can::Frame vel(double north_cms, double west_cms) const {
    return roles.encode(Role::InsVelEast,
                        {{Role::InsVelNorth, north_cms}, {Role::InsVelEast, west_cms}});
  }
  /// INS_TimeStamp, ms.
  [[nodiscard]] can::Frame time(double ms) const {
    return roles.encode(Role::InsTime, {{Role::InsTime, ms}});
  }
};

/// The error text of a configuration that does not resolve.
std::string refusal(const std::string& from, const std::string& to, const std::string& from2 = "",
                    const std::string& to2 = "") {
  std::string text = stand_text(from, to);
  if (!from2.empty()) {
    const auto at = text.find(from2);
    REQUIRE(at != std::string::npos);
    text.replace(at, from2.size(), to2);
  }
  auto c = parse_config(text, kStandFile);
  if (!c) return c.error().describe();
  auto d = load_databases(c->can);
  if (!d) return d.error().describe();
  auto r = resolve_roles(c->can, *d);
  return r ? "" : r.error().describe();
}

}  // namespace

TEST_SUITE("INS layouts") {
  TEST_CASE("one frame: West in cm/s becomes East in m/s, timed by the time frame before it") {
    Nav n;
    auto in = n.ingest();
    // 12.34 cm/s North, 5.67 cm/s West, at 1000.25 s on the INS clock
    CHECK(std::holds_alternative<std::monostate>(in->on_frame(Nav::at(10.0, n.time(1000250.0)))));
    const Sample s = in->on_frame(Nav::at(10.0002, n.vel(12.34, 5.67)));
    const auto* v = std::get_if<VelocitySample>(&s);
    REQUIRE(v != nullptr);
    CHECK(v->vn == doctest::Approx(0.1234).epsilon(1e-9));
    CHECK(v->ve == doctest::Approx(-0.0567).epsilon(1e-9));
    CHECK(v->t_ins_s == doctest::Approx(1000.25).epsilon(1e-12));
    CHECK(v->host_s == doctest::Approx(10.0002).epsilon(1e-12));
    // a time frame stamps one sample only: the next velocity without its
    // own is left out and counted, never given the old time
    CHECK(std::holds_alternative<std::monostate>(in->on_frame(Nav::at(10.01, n.vel(1, 1)))));
    CHECK(in->counters().velocity_untimed == 1);
    // a time frame older than time_frame_max_age_ms (5 ms) stamps nothing
    in->on_frame(Nav::at(10.02, n.time(1000270.0)));
    CHECK(std::holds_alternative<std::monostate>(in->on_frame(Nav::at(10.0261, n.vel(1, 1)))));
    CHECK(in->counters().velocity_untimed == 2);
    // and one within it does
    in->on_frame(Nav::at(10.03, n.time(1000280.0)));
    const Sample s2 = in->on_frame(Nav::at(10.0349, n.vel(-3, 4)));
    REQUIRE(std::holds_alternative<VelocitySample>(s2));
    CHECK(std::get<VelocitySample>(s2).t_ins_s == doctest::Approx(1000.28).epsilon(1e-12));
    CHECK(in->health(kVelocity).frames == 2);
  }

  TEST_CASE("the time frame wraps as its signal does: 2^32 us given in ms") {
    Nav n;
    auto in = n.ingest();
    const double wrap_ms = 4294967.296;
    in->on_frame(Nav::at(1.0, n.time(wrap_ms - 10)));
    const Sample a = in->on_frame(Nav::at(1.0001, n.vel(0, 0)));
    in->on_frame(Nav::at(1.02, n.time(10)));
    const Sample b = in->on_frame(Nav::at(1.0201, n.vel(0, 0)));
    REQUIRE(std::holds_alternative<VelocitySample>(a));
    REQUIRE(std::holds_alternative<VelocitySample>(b));
    CHECK(std::get<VelocitySample>(b).t_ins_s - std::get<VelocitySample>(a).t_ins_s ==
          doctest::Approx(0.020).epsilon(1e-9));
  }

  TEST_CASE("the receive time, on a clock of the nominal rate: late frames keep their slot") {
    Nav n("time = \"time-frame\"", "time = \"receive\"");
    auto in = n.ingest();
    // 100 Hz, each frame 0.2 to 2 ms late, every 97th 4.9 ms late (under
    // half a period), two frames lost (k = 300, 301)
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> late(0.0002, 0.002);
    int kept = 0;
    for (int k = 0; k < 1000; ++k) {
      if (k == 300 || k == 301) continue;
      const double host = 50 + 0.01 * k + (k % 97 == 0 ? 0.0049 : late(rng));
      const Sample s = in->on_frame(Nav::at(host, n.vel(1, 1)));
      const auto* v = std::get_if<VelocitySample>(&s);
      REQUIRE(v != nullptr);
      CHECK(std::llround(v->t_ins_s * 100) == k);  // the first frame's slot is 0
      ++kept;
    }
    CHECK(kept == 998);
    CHECK(in->health(kVelocity).dropped == 2);
    CHECK(in->counters().velocity_untimed == 0);
    // one frame 7 ms late takes the next one's slot; that one, on time, is
    // left out and counted, and the frames after it keep their slots
    const double t0 = 50 + 0.01 * 1000;
    const Sample late_one = in->on_frame(Nav::at(t0 + 0.007, n.vel(1, 1)));
    REQUIRE(std::holds_alternative<VelocitySample>(late_one));
    CHECK(std::llround(std::get<VelocitySample>(late_one).t_ins_s * 100) == 1001);
    CHECK(std::holds_alternative<std::monostate>(in->on_frame(Nav::at(t0 + 0.0102, n.vel(1, 1)))));
    CHECK(in->counters().velocity_untimed == 1);
    for (int k = 1002; k < 1010; ++k) {
      const Sample s = in->on_frame(Nav::at(50 + 0.01 * k + 0.001, n.vel(1, 1)));
      REQUIRE(std::holds_alternative<VelocitySample>(s));
      CHECK(std::llround(std::get<VelocitySample>(s).t_ins_s * 100) == k);
    }
  }

  TEST_CASE("a tag in the one frame: the reference INS's tag in the INS_NavVel frame") {
    // a DBC of one frame with its own tag: 24-bit tag in 100 us steps
    const std::string dbc =
        "VERSION \"\"\nBU_: HOST INS\n"
        "BO_ 291 INS_V: 8 INS\n"
        " SG_ Tag : 0|24@1+ (100,0) [0|0] \"us\" HOST\n"
        " SG_ VE : 24|20@1- (0.001,0) [0|0] \"m/s\" HOST\n"
        " SG_ VN : 44|20@1- (0.001,0) [0|0] \"m/s\" HOST\n";
    auto db = can::parse_dbc(dbc, "one.dbc");
    REQUIRE(db.ok());
    RoleMap roles;
    auto put = [&](Role r, const char* sig) {
      const can::Message* m = db->find("INS_V");
      const can::Signal* s = m->find_signal(sig);
      roles.roles[static_cast<std::size_t>(r)] = {m, s,
                                                  static_cast<std::size_t>(s - m->signals.data())};
    };
    put(Role::InsVelEast, "VE");
    put(Role::InsVelNorth, "VN");
    put(Role::InsVelEastTimeTag, "Tag");
    auto ins = drivers::make_ins(InsLayout{}, roles, Plausibility{}, 1);
    can::FrameCodec codec(*db);
    std::vector<double> values(3);
    auto decode = [&](double tag_us, double ve, double vn) {
      const std::vector<double> raw = {tag_us, ve, vn};
      const can::Frame f = can::FrameCodec::encode(*db->find("INS_V"), raw);
      const can::Message* m = nullptr;
      const auto st = codec.decode(f, values, &m);
      return ins->decode(FrameView{f, 1.0, m, st, values});
    };
    const Decoded d = decode(16777215.0 * 100 - 100, 0.123, -0.456);  // just before the wrap
    REQUIRE(d.verdict == Decoded::Verdict::Taken);
    CHECK(std::get<VelocitySample>(d.sample).ve == doctest::Approx(0.123).epsilon(1e-9));
    CHECK(std::get<VelocitySample>(d.sample).vn == doctest::Approx(-0.456).epsilon(1e-9));
    const Decoded w = decode(100, 0, 0);  // after the 2^24 x 100 us wrap
    REQUIRE(w.verdict == Decoded::Verdict::Taken);
    CHECK(w.device_s - d.device_s == doctest::Approx(0.0003).epsilon(1e-6));
  }

  TEST_CASE("a role's signal without a unit is read as m/s or us, and that is said") {
    // what turncalctl check and turncald's log print for a unitless DBC
    CHECK(unitless_role_warnings(Nav().roles).empty());  // every unit given
    const Nav counter("ins_time = \"INS_TimeStamp.TimeMs\"",
                      "ins_time = \"INS_TimeStamp.Counter\"");
    const auto w = unitless_role_warnings(counter.roles);
    REQUIRE(w.size() == 1);
    CHECK(w[0] ==
          "INS_TimeStamp.Counter (role ins_time) has no unit in the DBC: read as microseconds");
  }

  TEST_CASE("a layout that cannot be is refused, naming the file, line and key") {
    auto body = refusal("velocity_axes = \"navigation\"", "velocity_axes = \"body\"");
    CHECK(body.find("turncal.toml:") != std::string::npos);
    CHECK(body.find("ins.velocity_axes") != std::string::npos);
    CHECK(body.find("attitude") != std::string::npos);
    auto rate = refusal("velocity_rate_hz = 100", "velocity_rate_hz = 0");
    CHECK(rate.empty());  // time-frame needs no rate
    auto receive = refusal("velocity_rate_hz = 100", "velocity_rate_hz = 0",
                           "time = \"time-frame\"", "time = \"receive\"");
    CHECK(receive.find("ins.time") != std::string::npos);
    CHECK(receive.find("velocity_rate_hz") != std::string::npos);
    auto sign = refusal("east_sign = -1", "east_sign = 0.5");
    CHECK(sign.find("ins.east_sign") != std::string::npos);
    CHECK(sign.find("1 or -1") != std::string::npos);
    // a velocity signal whose unit is no speed
    auto unit = refusal("ins_vel_east = \"INS_NavVel.VelW\"",
                        "ins_vel_east = \"INS_NavVel.VelW\"\nins_vel_up = \"x.y\"");
    CHECK(unit.find("unknown role 'can.roles.ins_vel_up'") != std::string::npos);
    auto deg =
        refusal("ins_time = \"INS_TimeStamp.TimeMs\"", "ins_time = \"INS_TimeStamp.Counter\"");
    CHECK(deg.empty());  // a unitless counter is taken as microseconds
    auto speed =
        refusal("ins_vel_east = \"INS_NavVel.VelW\"", "ins_vel_east = \"INS_Command.HeadingInit\"");
    CHECK(speed.find("can.roles.ins_vel_east") != std::string::npos);
    CHECK(speed.find("'deg' is no velocity unit") != std::string::npos);
    // without tags, two frames cannot be paired
    auto two =
        refusal("ins_vel_north = \"INS_NavVel.VelN\"", "ins_vel_north = \"INS_TimeStamp.Counter\"");
    CHECK(two.find("one frame") != std::string::npos);
    CHECK(two.find("turncal.toml:") != std::string::npos);
    // the time-frame layout needs its time frame
    auto none = refusal("ins_time = \"INS_TimeStamp.TimeMs\"", "ins_time = \"\"");
    CHECK(none.find("can.roles.ins_time") != std::string::npos);
    auto proto = refusal("protocol = \"reference\"", "protocol = \"canopen\"");
    CHECK(proto.find("table.protocol") != std::string::npos);
  }
}
