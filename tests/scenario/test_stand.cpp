// The virtual stand as CAN nodes of the reference DBC (can-icd.md): a
// host-like script talks to it in frames only, as turncald will.
#include <doctest/doctest.h>

#include <map>

#include "scenarios.hpp"
#include "turncal/build_paths.hpp"
#include "turncal/sim/virtual_stand.hpp"

using namespace turncal;
using namespace turncal::stand;
using namespace scenario;

namespace {

struct Host {
  can::Database db;
  RoleMap roles;
  can::FrameCodec codec;
  std::uint8_t seq = 0;
  explicit Host(can::Database d, RoleMap r) : db(std::move(d)), roles(r), codec(db) {}
  can::Frame frame(Role any, std::initializer_list<std::pair<Role, double>> values) {
    return roles.encode(any, values);
  }
  can::Frame table(TableCommandCode c, double target_deg = 0, double rate_dps = 0) {
    return frame(Role::TableCommand, {{Role::TableCommand, static_cast<double>(c)},
                                      {Role::TableCommandSeq, ++seq},
                                      {Role::TableCommandTarget, target_deg},
                                      {Role::TableCommandRateLimit, rate_dps}});
  }
  can::Frame align(double duration_s, double heading_deg) {
    return frame(Role::InsCommand, {{Role::InsCommand, 1},
                                    {Role::InsCommandAlignDuration, duration_s},
                                    {Role::InsCommandHeading, heading_deg},
                                    {Role::InsCommandSeq, ++seq}});
  }
  can::Frame heartbeat(std::uint8_t counter) {
    return frame(Role::HeartbeatCounter,
                 {{Role::HeartbeatCounter, counter}, {Role::HeartbeatState, 1}});
  }
  double value(const can::Frame& f, Role r) {
    std::vector<double> v(16);
    const can::Message* m = nullptr;
    REQUIRE(codec.decode(f, v, &m) == can::DecodeStatus::Ok);
    REQUIRE(m == roles[r].message);
    return v[roles[r].signal_index];
  }
};

Host reference_host() {
  auto cfg = parse_config("", std::string(turncal::build::source_dir) + "/config/turncal.toml");
  REQUIRE(cfg.ok());
  auto db = load_databases(cfg->can);
  REQUIRE(db.ok());
  Host h(std::move(*db), RoleMap{});
  auto roles = resolve_roles(cfg->can, h.db);
  REQUIRE(roles.ok());
  h.roles = *roles;
  return h;
}

StandSetup short_setup() {
  StandSetup s;
  const Scenario sc = tactical();
  std::mt19937_64 rng(5);
  s.ins.sim = sim_config(sc, draw(sc, rng), 0, 11);
  s.ins.heading_offset_rad = 0;
  s.table_angle0_rad = 350 * kDeg;  // the encoder wraps during the turn
  s.ins_clock = {1000.25, 50};      // different clocks: offset, 50 ppm fast
  s.table_clock = {4294.0, -30};    // the table's tags wrap at 4294.967296 s
  return s;
}

/// Runs the script: enable at 1 s, align 20 s from 2 s, turn +180 deg 30 s
/// after t0, heartbeat at 10 Hz while `heartbeat_until`; ticks of 1 ms.
std::vector<StandFrame> run(VirtualStand& stand, Host& host, double until,
                            double heartbeat_until = 1e9) {
  std::vector<StandFrame> out;
  std::uint8_t hb = 0;
  bool turned = false;
  for (long k = 0; k <= static_cast<long>(until * 1000); ++k) {
    const double t = static_cast<double>(k) / 1000;
    stand.advance(t, out);
    if (k % 100 == 0 && t <= heartbeat_until) stand.receive(t, host.heartbeat(hb++));
    if (k == 1000) stand.receive(t, host.table(TableCommandCode::Enable));
    if (k == 2000) stand.receive(t, host.align(20, -350));  // heading of z2 = offset - angle
    if (!turned && !std::isnan(stand.ins().t0()) && t >= stand.ins().t0() + 30) {
      stand.receive(t, host.table(TableCommandCode::MoveRelative, 180, 30));
      turned = true;
    }
  }
  return out;
}

}  // namespace

TEST_SUITE("virtual stand") {
  TEST_CASE("frames conform to the ICD: decodable, at their rates, tags on two clocks") {
    Host host = reference_host();
    VirtualStand stand(short_setup(), host.db, host.roles);
    const auto out = run(stand, host, 60);
    std::map<std::string, std::vector<const StandFrame*>> by;
    for (const StandFrame& f : out) {
      const can::Message* m = nullptr;
      std::vector<double> v(16);
      REQUIRE(host.codec.decode(f.frame, v, &m) == can::DecodeStatus::Ok);
      by[m->name].push_back(&f);
    }
    CHECK(stand.counts().host_undecodable == 0);
    // rates within 1% over the 60 s (velocity from t0 = 22 s)
    CHECK(by["INS_Status"].size() == doctest::Approx(600).epsilon(0.01));
    CHECK(by["TBL_Encoder"].size() == doctest::Approx(12000).epsilon(0.01));
    CHECK(by["TBL_Status"].size() == doctest::Approx(1200).epsilon(0.01));
    CHECK(by["INS_VelE"].size() == doctest::Approx(3800).epsilon(0.01));
    CHECK(by["INS_VelN"].size() == by["INS_VelE"].size());
    // pairs share their time tag; INS tags step 10 ms at +50 ppm
    const auto& e = by["INS_VelE"];
    const auto& n = by["INS_VelN"];
    for (std::size_t i = 0; i < e.size(); i += 97)
      CHECK(host.value(e[i]->frame, Role::InsVelEastTimeTag) ==
            host.value(n[i]->frame, Role::InsVelNorthTimeTag));
    const double d = host.value(e[1000]->frame, Role::InsVelEastTimeTag) -
                     host.value(e[0]->frame, Role::InsVelEastTimeTag);
    CHECK(d == doctest::Approx(10e6 * (1 + 50e-6)).epsilon(1e-6));
    // table tags wrap (2^32 us) within the run; the encoder angle wraps at
    // 360 deg during the turn and, unwrapped, ends 180 deg on
    bool tag_wrapped = false, angle_wrapped = false;
    double prev_tag = -1, prev_angle = -1, unwrapped = 0;
    for (const StandFrame* f : by["TBL_Encoder"]) {
      const double tag = host.value(f->frame, Role::EncoderTimeTag);
      const double a = host.value(f->frame, Role::EncoderAngle);
      if (prev_tag >= 0 && tag < prev_tag) tag_wrapped = true;
      if (prev_angle >= 0) {
        double step = a - prev_angle;
        if (step < -180) {
          step += 360;
          angle_wrapped = true;
        }
        unwrapped += step;
      }
      prev_tag = tag;
      prev_angle = a;
    }
    CHECK(tag_wrapped);
    CHECK(angle_wrapped);
    CHECK(unwrapped == doctest::Approx(180).epsilon(1e-6));
    // the INS went idle -> aligning -> navigating; the move was acknowledged
    CHECK(host.value(by["INS_Status"].front()->frame, Role::InsMode) == 0);
    CHECK(host.value(by["INS_Status"].back()->frame, Role::InsMode) == 2);
    const StandFrame* last = by["TBL_Status"].back();
    CHECK(host.value(last->frame, Role::TableState) == static_cast<double>(TableState::InPosition));
    CHECK(host.value(last->frame, Role::TableAck) == host.seq);
    // time order
    for (std::size_t i = 1; i < out.size(); ++i) REQUIRE(out[i].t_s >= out[i - 1].t_s);
  }

  TEST_CASE("heartbeat loss while the table moves: quick stop, state 5, fault 1") {
    Host host = reference_host();
    VirtualStand stand(short_setup(), host.db, host.roles);
    const auto out = run(stand, host, 60, 53.0);  // the turn starts at 52 s
    double stopped_at = -1;
    for (const StandFrame& f : out)
      if (f.frame.id == host.roles[Role::TableState].message->id &&
          host.value(f.frame, Role::TableState) == 5 && stopped_at < 0) {
        stopped_at = f.t_s;
        CHECK(host.value(f.frame, Role::TableFault) == 1);
      }
    CHECK(stopped_at == doctest::Approx(53.5).epsilon(0.002));  // next 20 Hz status
    CHECK(stand.table().angle(60) < 60 * kDeg + 350 * kDeg);
  }

  TEST_CASE("silence timed from the table's first turn") {
    Host host = reference_host();
    StandSetup s = short_setup();
    s.faults.ins_silent_after_turn_s = 2;
    s.faults.encoder_silent_after_turn_s = 3;
    VirtualStand stand(s, host.db, host.roles);
    const auto out = run(stand, host, 60);
    double first_angle = NAN, turn_at = NAN, last_ins = NAN, last_encoder = NAN;
    for (const StandFrame& f : out) {
      const can::Message* m = nullptr;
      std::vector<double> v(16);
      REQUIRE(host.codec.decode(f.frame, v, &m) == can::DecodeStatus::Ok);
      if (f.ins_side) last_ins = f.t_s;
      if (m->name != "TBL_Encoder") continue;
      last_encoder = f.t_s;
      const double a = v[host.roles[Role::EncoderAngle].signal_index];
      if (std::isnan(first_angle)) first_angle = a;
      if (std::isnan(turn_at) && a != first_angle) turn_at = f.t_s;
    }
    REQUIRE(turn_at > 50);  // the turn starts at 52 s
    // the INS (its 100 Hz velocity and 10 Hz status) and the 200 Hz encoder
    // stop within a period of their times after the turn's start
    CHECK(last_ins < turn_at + 2);
    CHECK(last_ins > turn_at + 2 - 0.02);
    CHECK(last_encoder < turn_at + 3);
    CHECK(last_encoder > turn_at + 3 - 0.01);
  }

  TEST_CASE("stand faults: drops, silence, garbage, flood, clock jump") {
    Host host = reference_host();
    StandSetup s = short_setup();
    s.faults.ins_drop_rate = 0.1;
    s.faults.encoder_silent_at_s = 40;
    s.faults.ins_silent_at_s = 50;
    s.faults.garbage_rate_hz = 2;
    s.faults.flood_at_s = 30;
    s.faults.flood_s = 1;
    s.faults.flood_rate_hz = 5000;
    s.table_clock.jump_at_s = 20;
    s.table_clock.jump_s = 0.5;
    VirtualStand stand(s, host.db, host.roles);
    const auto out = run(stand, host, 60);
    can::DecodeCounts counts;
    std::size_t vel = 0, enc_after = 0, ins_after = 0, flood = 0;
    double tag_before = 0, tag_after = 0;
    for (const StandFrame& f : out) {
      const can::Message* m = nullptr;
      std::vector<double> v(16);
      const auto st = host.codec.decode(f.frame, v, &m);
      counts.add(st);
      if (st != can::DecodeStatus::Ok) {
        if (f.t_s >= 30 && f.t_s < 31 && st == can::DecodeStatus::UnknownId) ++flood;
        continue;
      }
      if (m->name == "INS_VelE" || m->name == "INS_VelN") ++vel;
      if (m->name == "TBL_Encoder" && f.t_s >= 40) ++enc_after;
      if (f.ins_side && f.t_s >= 50) ++ins_after;
      if (m->name == "TBL_Encoder" && std::fabs(f.t_s - 19.995) < 1e-9)
        tag_before = v[host.roles[Role::EncoderTimeTag].signal_index];
      if (m->name == "TBL_Encoder" && std::fabs(f.t_s - 20.0) < 1e-9)
        tag_after = v[host.roles[Role::EncoderTimeTag].signal_index];
    }
    // 28 s of velocity pairs (22 s to 50 s), 10% of frames dropped: the
    // count of kept frames is binomial, sd 17; 5 sd either way
    CHECK(static_cast<double>(vel) == doctest::Approx(0.9 * 5600).epsilon(85.0 / 5040));
    CHECK(enc_after == 0);
    CHECK(ins_after == 0);
    CHECK(flood == doctest::Approx(5000).epsilon(0.01));
    CHECK(counts.length_mismatch >= 55);  // garbage: 2 Hz, half of known ID, wrong length
    CHECK(counts.unknown_id >= 5000 + 55);
    CHECK(tag_after - tag_before == doctest::Approx(0.5e6 + 5e3).epsilon(1e-3));
  }
}

#include <unistd.h>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "turncal/sim/scripted_host.hpp"

TEST_SUITE("virtual stand") {
  TEST_CASE("offline run: a plan's whole experiment into a candump log, reproducibly") {
    Host host = reference_host();
    auto plan = parse_plan(
        "[profile]\nduration_s = 120\nalign_s = 20\nstart_angle_deg = 10\n"
        "[[profile.turn]]\nstart_s = 60\nangle_deg = -180\nmax_rate_dps = 20\n"
        "max_accel_dps2 = 20\n",
        "short.toml");
    REQUIRE(plan.ok());
    auto cfg = parse_config("[can]\nins_interface = \"can1\"\ntable_interface = \"can2\"\n",
                            std::string(turncal::build::source_dir) + "/config/turncal.toml");
    REQUIRE(cfg.ok());
    StandSetup setup = short_setup();
    setup.table_angle0_rad = plan->start_angle_rad;
    setup.ins.heading_offset_rad = 15 * kDeg;
    const auto dir = std::filesystem::temp_directory_path();
    const std::string pid = std::to_string(::getpid());
    const std::string a = (dir / ("turncal-offline-a-" + pid + ".log")).string();
    const std::string b = (dir / ("turncal-offline-b-" + pid + ".log")).string();
    for (const std::string& path : {a, b}) {
      auto log = can::LogWriter::open(path);
      REQUIRE(log.ok());
      REQUIRE(run_offline(*plan, cfg->can, host.db, host.roles, setup, *log, 1.7e9).ok());
      REQUIRE(log->close().ok());
    }
    auto slurp = [](const std::string& p) {
      std::ifstream in(p);
      std::stringstream ss;
      ss << in.rdbuf();
      return ss.str();
    };
    CHECK(slurp(a) == slurp(b));  // same seed, same bytes

    auto rd = can::LogReader::open(a);
    REQUIRE(rd.ok());
    can::LogRecord rec;
    std::map<std::string, int> count;
    std::map<std::string, std::string> iface;
    double heading = NAN, last_angle = NAN, first_t = NAN, last_t = NAN;
    double last_ack = -1, last_mode = -1;
    for (;;) {
      auto got = rd->next(rec);
      REQUIRE(got.ok());
      if (!*got) break;
      const can::Message* m = host.codec.message_for(rec.frame);
      REQUIRE(m != nullptr);
      ++count[m->name];
      iface[m->name] = rec.interface;
      const double t = static_cast<double>(rec.time_ns) * 1e-9 - 1.7e9;
      if (std::isnan(first_t)) first_t = t;
      last_t = t;
      if (m->name == "INS_Command") heading = host.value(rec.frame, Role::InsCommandHeading);
      if (m->name == "TBL_Encoder") last_angle = host.value(rec.frame, Role::EncoderAngle);
      if (m->name == "TBL_Status") last_ack = host.value(rec.frame, Role::TableAck);
      if (m->name == "INS_Status") last_mode = host.value(rec.frame, Role::InsMode);
    }
    std::filesystem::remove(a);
    std::filesystem::remove(b);
    // the host's commands and heartbeats are in the log too, on their buses
    CHECK(count["INS_Command"] == 1);
    CHECK(count["TBL_Command"] == 2);  // enable, the turn
    CHECK(iface["INS_Command"] == "can1");
    CHECK(iface["TBL_Command"] == "can2");
    CHECK(iface["INS_VelE"] == "can1");
    CHECK(iface["TBL_Encoder"] == "can2");
    CHECK(heading == doctest::Approx(15 - 10));  // heading_offset - angle
    CHECK(count["INS_VelE"] == 12001);           // 100 Hz from t0 to t0 + 120 s
    CHECK(count["INS_VelN"] == 12001);
    CHECK(last_angle == doctest::Approx(190).epsilon(1e-6));  // 10 - 180, wrapped
    CHECK(last_ack == 3);  // Seq 1 enable, 2 the INS command, 3 the turn
    CHECK(last_mode == 2);
    CHECK(first_t == 0);
    CHECK(last_t == doctest::Approx(2 + 20 + 120).epsilon(1e-3));
    CHECK(count["HOST_Heartbeat"] == doctest::Approx(10 * 142).epsilon(0.01));
  }
}
