// What goes to the stand fits its command signals: the plan check refuses
// a plan that would not, and the engine never sends a clipped command.
#include <doctest/doctest.h>

#include <cmath>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "turncal/build_paths.hpp"
#include "turncal/run/engine.hpp"
#include "turncal/run/sequencer.hpp"

using namespace turncal;
using namespace turncal::run;

namespace {

constexpr double kDeg = std::numbers::pi / 180;

/// The reference stand's database and roles (the shipped DBC).
struct Stand {
  can::Database db;
  RoleMap roles;
  Stand() {
    auto c = parse_config("", std::string(turncal::build::source_dir) + "/config/turncal.toml");
    REQUIRE(c.ok());
    auto d = load_databases(c->can);
    REQUIRE_MESSAGE(d.ok(), (d.ok() ? "" : d.error().describe()));
    db = std::move(*d);
    cfg = *c;
    resolve();
  }
  void resolve() {
    auto r = resolve_roles(cfg.can, db);
    REQUIRE(r.ok());
    roles = *r;
  }
  can::Signal& signal(const char* message, const char* name) {
    for (can::Message& m : db.messages)
      if (m.name == message)
        for (can::Signal& s : m.signals)
          if (s.name == name) return s;
    FAIL("no signal ", message, ".", name);
    throw 0;
  }
  Config cfg;
};

TurnSpec turn(double start_s, double angle_deg, double rate_dps = 20) {
  return {start_s, angle_deg * kDeg, rate_dps * kDeg, 20 * kDeg};
}

SequencerSettings two_turns(double second_deg, const RoleMap& roles) {
  SequencerSettings s;
  s.profile.duration_s = 7200;
  s.profile.align_s = 120;
  s.profile.turns = {turn(600, 180), turn(1800, second_deg)};
  s.limits.max_rate_rps = 30 * kDeg;
  s.limits.max_accel_rps2 = 30 * kDeg;
  s.commands = command_signals(roles);
  return s;
}

can::TimedFrame at(double t_s, const can::Frame& f) {
  return {static_cast<std::int64_t>(std::llround(t_s * 1e9)), f};
}

}  // namespace

TEST_SUITE("commands") {
  TEST_CASE("the command signals' ranges come from the DBC, ICD revision 2") {
    Stand st;
    const CommandSignals c = command_signals(st.roles);
    CHECK(c.target.name == "TBL_Command.Target");
    CHECK(c.target.range == "-21474.83648 to 21474.83647 deg");
    CHECK(c.target.hi == doctest::Approx(21474.83647 * kDeg));
    CHECK(c.rate_limit.range == "0.00 to 655.35 deg/s");
    CHECK(c.align_duration.range == "0 to 65535 s");
  }

  TEST_CASE("a 10-revolution move reaches the table whole; under revision 1 it is refused") {
    Stand st;
    auto move = [&](double deg) {
      return st.roles.encode_checked(Role::TableCommand, {{Role::TableCommand, 2},
                                                          {Role::TableCommandSeq, 7},
                                                          {Role::TableCommandTarget, deg},
                                                          {Role::TableCommandRateLimit, 30}});
    };
    const can::FrameCodec codec(st.db);
    for (double deg : {3600.0, -3600.0, 21474.83647, -21474.83648}) {
      CAPTURE(deg);
      auto f = move(deg);
      REQUIRE(f.ok());
      std::vector<double> v(4);
      REQUIRE(codec.decode(*f, v) == can::DecodeStatus::Ok);
      CHECK(v[st.roles[Role::TableCommandTarget].signal_index] ==
            doctest::Approx(deg).epsilon(1e-12));
    }
    CHECK_FALSE(move(21474.8365).ok());
    can::Signal& target = st.signal("TBL_Command", "Target");
    target.factor = 1e-6;
    target.minimum = -2147.483648;
    target.maximum = 2147.483647;
    st.resolve();
    auto f = move(3600);
    REQUIRE_FALSE(f.ok());  // it used to go out as 2147.483647 deg
    CHECK(f.error().message ==
          "3600 deg does not fit TBL_Command.Target (-2147.483648 to 2147.483647 deg)");
  }

  TEST_CASE("the plan check refuses moves that do not fit the command signals, naming the turn") {
    Stand st;
    SUBCASE("a 30000 deg turn does not fit TBL_Command.Target") {
      CHECK(check_plan(two_turns(30000, st.roles)) ==
            "turn 2: target 30000 deg does not fit TBL_Command.Target (-21474.83648 to "
            "21474.83647 deg)");
      CHECK(check_plan(two_turns(-30000, st.roles)).find("turn 2: target -30000 deg") == 0);
    }
    SUBCASE("10 revolutions fit revision 2; revision 1 (1e-6 deg) would have clipped them") {
      CHECK(check_plan(two_turns(3600, st.roles)).empty());
      CHECK(check_plan(two_turns(-3600, st.roles)).empty());
      can::Signal& target = st.signal("TBL_Command", "Target");
      target.factor = 1e-6;
      target.minimum = -2147.483648;
      target.maximum = 2147.483647;
      st.resolve();
      CHECK(check_plan(two_turns(3600, st.roles)) ==
            "turn 2: target 3600 deg does not fit TBL_Command.Target (-2147.483648 to "
            "2147.483647 deg)");
    }
    SUBCASE("a rate beyond TBL_Command.RateLimit") {
      SequencerSettings s = two_turns(360, st.roles);
      s.limits.max_rate_rps = 1000 * kDeg;
      s.profile.turns[0].max_rate_rps = 700 * kDeg;
      CHECK(check_plan(s) ==
            "turn 1: rate 700 deg/s does not fit TBL_Command.RateLimit (0.00 to 655.35 deg/s)");
    }
    SUBCASE("the move to the start angle and the alignment") {
      SequencerSettings s = two_turns(360, st.roles);
      s.commands.target.lo = -90 * kDeg;
      s.commands.target.range = "-90 to 21474.83647 deg";
      CHECK(check_plan(s).find("the move to the start angle: target 180 deg does not fit") == 0);
      s = two_turns(360, st.roles);
      s.profile.align_s = 1e5;
      CHECK(check_plan(s) ==
            "the alignment: length 100000 s does not fit INS_Command.AlignDuration (0 to 65535 s)");
    }
    SUBCASE("observe mode sends nothing: the command signals do not limit it") {
      SequencerSettings s = two_turns(30000, st.roles);
      s.observe = true;
      CHECK(check_plan(s).empty());
    }
  }

  TEST_CASE("the engine refuses such a plan at the start, before any command") {
    Stand st;
    Plan plan;
    plan.profile = two_turns(30000, st.roles).profile;
    SequencerSettings q = two_turns(30000, st.roles);
    q.commands = {};  // the engine sets them from its roles
    Engine e(st.db, st.roles, plan, q, BuildSettings{}, TimeBase{});
    std::vector<OutFrame> out;
    e.start(0, out);
    CHECK(out.empty());
    CHECK(e.sequencer().phase() == Phase::Failed);
    CHECK(e.sequencer().course().reason ==
          "refused before any command: turn 2: target 30000 deg does not fit TBL_Command.Target "
          "(-21474.83648 to 21474.83647 deg)");
  }

  TEST_CASE("an engine's record asks for huge pages only when told it replays") {
    // the daemon's loop must not stall on a huge page's first touch
    Stand st;
    Plan plan;
    plan.profile = two_turns(180, st.roles).profile;
    Engine e(st.db, st.roles, plan, two_turns(180, st.roles), BuildSettings{}, TimeBase{});
    CHECK_FALSE(e.record().huge_pages());
    e.replaying();
    CHECK(e.record().huge_pages());
  }

  TEST_CASE("a command that does not fit at run time is not sent: the run fails, quick stop") {
    // A stand whose INS takes headings in -180..180 deg only: the heading
    // given at alignment (270 deg here) depends on where the table stands,
    // which no plan check can know.
    Stand st;
    can::Signal& heading = st.signal("INS_Command", "HeadingInit");
    heading.minimum = -180;
    heading.maximum = 180;
    st.resolve();
    Plan plan;
    plan.profile = two_turns(180, st.roles).profile;
    SequencerSettings q = two_turns(180, st.roles);
    q.heading_offset_rad = 270 * kDeg;
    Engine e(st.db, st.roles, plan, q, BuildSettings{}, TimeBase{});
    std::vector<OutFrame> out;
    e.start(0, out);
    CHECK(out.empty());  // enable goes with the table's first status
    e.on_frame(at(0.05, st.roles.encode(Role::TableState, {{Role::TableState, 0}})), out);
    REQUIRE(out.size() == 1);  // enable
    const can::FrameCodec codec(st.db);
    auto table_value = [&](const can::Frame& f, Role r) {
      std::vector<double> v(8);
      REQUIRE(codec.decode(f, v) == can::DecodeStatus::Ok);
      return v[st.roles[r].signal_index];
    };
    CHECK(table_value(out[0].frame, Role::TableCommand) == 4);
    CHECK_FALSE(out[0].urgent);  // only a quick stop goes before what waits
    const double seq = table_value(out[0].frame, Role::TableCommandSeq);
    out.clear();
    e.on_frame(at(0.1, st.roles.encode(Role::EncoderAngle,
                                       {{Role::EncoderAngle, 0}, {Role::EncoderTimeTag, 1e5}})),
               out);
    e.on_frame(
        at(0.2, st.roles.encode(Role::TableState, {{Role::TableState, 1}, {Role::TableAck, seq}})),
        out);
    // at the start angle already: the alignment is due, its command does not fit
    REQUIRE(out.size() == 1);
    CHECK_FALSE(out[0].ins_side);
    CHECK(table_value(out[0].frame, Role::TableCommand) ==
          static_cast<double>(TableCommandCode::QuickStop));
    CHECK(out[0].urgent);
    CHECK(e.sequencer().course().quick_stop_sent);
    CHECK(e.sequencer().course().reason ==
          "INS command not sent: 270 deg does not fit INS_Command.HeadingInit (-180.000000 to "
          "180.000000 deg)");
    e.on_frame(at(0.3, st.roles.encode(Role::TableState,
                                       {{Role::TableState, 5}, {Role::TableAck, seq + 1}})),
               out);
    CHECK(finished(e.sequencer().phase()));
    CHECK(e.sequencer().phase() != Phase::Done);
    CHECK(e.sequencer().phase() != Phase::Aborted);  // a fault, not the operator's abort
    CHECK(e.sequencer().course().quick_stop_acked);
  }
}

TEST_CASE("a frame's time is rounded as std::llround rounds it, without the call") {
  // halves either way, each side of them, the ends of the fast range and
  // past them, and a frame's stand time in microseconds
  std::vector<double> xs = {0.0,
                            -0.0,
                            0.5,
                            -0.5,
                            1.5,
                            -1.5,
                            2.5,
                            -2.5,
                            0.49999999999999994,
                            -0.49999999999999994,
                            1e-300,
                            -1e-300,
                            4503599627370495.5,
                            -4503599627370495.5,
                            0x1p52,
                            -0x1p52,
                            0x1p52 + 2,
                            -0x1p53,
                            1.7649792001234565e15,
                            9.2e18,
                            -9.2e18};
  std::mt19937_64 rng(20261206);
  std::uniform_real_distribution<double> frames(1.7e15, 1.8e15), small(-1e6, 1e6);
  for (int k = 0; k < 200000; ++k) {
    xs.push_back(frames(rng));
    xs.push_back(small(rng));
    xs.push_back(std::nextafter(std::floor(small(rng)) + 0.5, k % 2 == 0 ? 0.0 : 1e7));
    xs.push_back(std::floor(small(rng)) + 0.5);
  }
  int wrong = 0;
  for (const double x : xs) {
    if (round_half_away(x) == std::llround(x)) continue;
    if (++wrong <= 5) {
      CAPTURE(x);
      CHECK(round_half_away(x) == std::llround(x));
    }
  }
  CHECK(wrong == 0);
}
