// turncal-sim: the virtual stand (can-icd.md). Live, it emulates the INS
// and the table on the configured CAN interfaces, in real time or N times
// faster, for a host (turncald) to drive; with --scripted-host it drives
// itself through a plan as turncald would, its host frames on the bus too.
// Offline, it writes such a scripted run straight to a candump log, as fast
// as the CPU allows. Either way the injected errors, drawn from the plan's
// priors with the seed, can be written as JSON (SI, model.md's names).
//
//   turncal-sim [--speed N] [--scripted-host] [--truth TRUTH.json] [common]
//   turncal-sim --offline --out RUN.log --truth TRUTH.json [common]
//   common: [--profile PLAN.toml] [--config turncal.toml] [--seed N]
//           [--heading-offset DEG] [--ins-interface IF] [--table-interface IF]
//           [--start-time UNIX_S] (offline only)
#include <nlohmann/json.hpp>

#include <poll.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <deque>
#include <fstream>
#include <numeric>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "turncal/build_paths.hpp"
#include "turncal/can/candump.hpp"
#include "turncal/config.hpp"
#include "turncal/drivers/socketcan.hpp"
#include "turncal/earth.hpp"
#include "turncal/estimation/nominal.hpp"
#include "turncal/estimation/state.hpp"
#include "turncal/plan.hpp"
#include "turncal/sim/scripted_host.hpp"
#include "turncal/sim/virtual_stand.hpp"

using namespace turncal;

namespace {

constexpr double kDeg = 0.017453292519943295;

struct Options {
  bool offline = false;
  bool scripted_host = false;
  bool real_bus = false;  // may send on a CAN interface that is not virtual
  double speed = 1;
  std::string ins_interface, table_interface;
  std::string out, truth;
  std::string state_out;  // the stand's own state at exit, as JSON
  std::string profile = std::string(turncal::build::data_dir) + "/profiles/tactical.toml";
  std::string config = std::string(turncal::build::data_dir) + "/turncal.toml";
  std::uint64_t seed = 1;
  double heading_offset_deg = 0;
  double start_time_s = 1767225600;     // 2026-01-01T00:00:00Z: runs are reproducible
  std::vector<std::string> faults;      // NAME=V[:V...]
  std::vector<std::string> drive_ways;  // a CiA 402 drive's behaviours, NAME[=V[:V]]
  std::string ins_clock, table_clock;   // OFFSET_S:PPM
  std::string angle_limits;             // MIN_DEG:MAX_DEG
  std::string heartbeat_timeout;        // the table's, stand s
  std::string truth_in;                 // errors given in a JSON file
  std::string rates;                    // VELOCITY_HZ:ENCODER_HZ[:INS_STATUS_HZ:TABLE_STATUS_HZ]
};

constexpr const char* kFaultHelp =
    "faults (--fault NAME=VALUE, repeatable; times are stand seconds from the start):\n"
    "  ins-drop=FRACTION          INS velocity frames dropped at random\n"
    "  ins-spikes=FRACTION        INS velocity East frames sent as 2000 m/s at random\n"
    "  ins-burst=AT:SECONDS       every INS frame dropped for a while\n"
    "  ins-silent=AT|turn+S       the INS sends nothing from then on (turn+S: S after\n"
    "                             the table first turns)\n"
    "  ins-fault=AT               the INS goes to fault mode (3)\n"
    "  encoder-silent=AT|turn+S   no TBL_Encoder from then on (a CiA 402 drive: AT only)\n"
    "  table-stall=SECONDS        the next move stalls this long after it starts\n"
    "  table-overshoot=DEG        moves pass their target by DEG, then come back\n"
    "  table-fault=AT             a drive fault: quick stop, state 4, fault 3\n"
    "  table-off-target=DEG       moves end DEG past (< 0: short of) their target, reported\n"
    "                             in position\n"
    "  table-drift=AT:DEG         the table at rest turns DEG by itself, still holding\n"
    "  garbage=HZ                 frames of wrong length and of unknown IDs\n"
    "  flood=AT:SECONDS[:HZ]      a flood of unknown frames (default 5000 Hz)\n"
    "  clock-jump=ins|table:AT:S  a device clock jumps by S seconds\n"
    "with [table] protocol = \"cia402\" the table is a CiA 402 drive; its faults:\n"
    "  table-fault=AT             a drive fault: EMCY 0x2310, Fault\n"
    "  drive-following-error=AT   statusword bit 13, EMCY 0x8611, Fault\n"
    "  drive-silent=AT:SECONDS    the drive neither sends nor hears: it loses the host\n"
    "                             heartbeat (EMCY 0x8130, 0x6007), the host loses its\n"
    "  drive-refuse-moves=1       set-points are never acknowledged\n"
    "  drive-warning-in-move=S    S seconds into the first move, an EMCY that only\n"
    "                             warns (0x4210): the drive would go on turning\n"
    "a CiA 402 drive's ways, as real drives have them (--drive NAME[=VALUE], repeatable):\n"
    "  sdo-answer=MIN_MS:MAX_MS   each SDO answer this late, spread between the two\n"
    "  no-target-reached-in-quick-stop  statusword bit 10 never set in quick stop active\n"
    "  quick-stop-bit-where-free  statusword bit 5 set where CiA 402 leaves it free\n"
    "                             (switch on disabled 0x0260, fault 0x0228)\n"
    "  set-point-ack-after-enable=S  statusword bit 12 up S s after each enable (inf: for\n"
    "                             good), a set-point's bit 4 meanwhile not taken\n"
    "  warning-at-boot=CODE       an EMCY that only warns after each boot-up (hex)\n"
    "  absent=INDEX[:INDEX...]    objects the drive does not have (hex; every access\n"
    "                             aborted with 0x06020000), as 60F2, 605B, 605C\n";

/// Numbers separated by ':'.
bool numbers(const std::string& text, std::vector<double>& out) {
  out.clear();
  std::size_t pos = 0;
  while (pos <= text.size()) {
    const std::size_t end = std::min(text.find(':', pos), text.size());
    const std::string part = text.substr(pos, end - pos);
    char* stop = nullptr;
    const double v = std::strtod(part.c_str(), &stop);
    if (part.empty() || *stop != '\0' || !std::isfinite(v)) return false;
    out.push_back(v);
    pos = end + 1;
  }
  return true;
}

/// A CiA 402 drive's behaviour, NAME[=VALUE] (kFaultHelp's list).
Status apply_drive_way(const std::string& spec, stand::StandSetup& s) {
  const std::size_t eq = spec.find('=');
  const std::string name = spec.substr(0, eq);
  const std::string value = eq == std::string::npos ? "" : spec.substr(eq + 1);
  const auto bad = [&] {
    return make_error("--drive " + spec + ": unknown behaviour or wrong value\n" + kFaultHelp);
  };
  if (!s.cia402) return make_error("--drive " + spec + ": the table is no CiA 402 drive");
  stand::Drive402Setup& d = s.drive;
  if (name == "no-target-reached-in-quick-stop" && value.empty()) {
    d.target_reached_in_quick_stop = false;
  } else if (name == "quick-stop-bit-where-free" && value.empty()) {
    d.quick_stop_bit_where_free = true;
  } else if (name == "set-point-ack-after-enable") {
    char* end = nullptr;
    const double v = std::strtod(value.c_str(), &end);
    if (value.empty() || *end != '\0' || !(v > 0)) return bad();
    d.set_point_ack_after_enable_s = v;
  } else if (name == "sdo-answer") {
    std::vector<double> v;
    if (!numbers(value, v) || v.size() != 2 || !(v[0] >= 0 && v[1] >= v[0] && v[1] <= 1000))
      return bad();
    d.sdo_answer_min_s = v[0] / 1000;
    d.sdo_answer_max_s = v[1] / 1000;
  } else if (name == "absent") {
    std::size_t pos = 0;
    while (pos <= value.size()) {
      const std::size_t end = std::min(value.find(':', pos), value.size());
      const std::string part = value.substr(pos, end - pos);
      char* stop = nullptr;
      const unsigned long index = std::strtoul(part.c_str(), &stop, 16);
      if (part.empty() || *stop != '\0' || index < 0x1000 || index > 0xFFFF) return bad();
      // every sub-index of it (CiA 301: the object does not exist)
      for (std::uint32_t sub = 0; sub < 256; ++sub)
        s.drive_faults.refuse_objects[static_cast<std::uint32_t>(index) << 8 | sub] = 0x06020000;
      pos = end + 1;
    }
  } else if (name == "warning-at-boot") {
    char* end = nullptr;
    const unsigned long code = std::strtoul(value.c_str(), &end, 16);
    if (value.empty() || *end != '\0' || code == 0 || code > 0xFFFF) return bad();
    d.boot_warning_code = static_cast<std::uint16_t>(code);
  } else {
    return bad();
  }
  return Ok{};
}

/// A CiA 402 drive's faults; false when `name` is none of them.
bool apply_drive_fault(const std::string& name, const std::vector<double>& v,
                       stand::StandSetup& s) {
  stand::Drive402Faults& d = s.drive_faults;
  if (name == "table-fault" && v.size() == 1) {
    d.fault_at_s = v[0];
  } else if (name == "drive-following-error" && v.size() == 1) {
    d.following_error_at_s = v[0];
  } else if (name == "drive-silent" && v.size() == 2 && v[1] > 0) {
    d.silent_at_s = v[0];
    d.silent_until_s = v[0] + v[1];
  } else if (name == "drive-warning-in-move" && v.size() == 1 && v[0] >= 0) {
    d.warning_after_move_s = v[0];
  } else if (name == "drive-refuse-moves" && v.size() == 1) {
    d.refuse_moves = v[0] != 0;
  } else {
    return false;
  }
  return true;
}

Status apply_fault(const std::string& spec, stand::StandSetup& s) {
  const std::size_t eq = spec.find('=');
  const std::string name = spec.substr(0, eq);
  std::string value = eq == std::string::npos ? "" : spec.substr(eq + 1);
  if (s.cia402 &&
      (name.starts_with("table-") || name.starts_with("drive-") || name == "encoder-silent" ||
       (name == "clock-jump" && value.starts_with("table")))) {
    // the drive has faults of its own; the reference table's do not apply
    std::vector<double> v;
    if (numbers(value, v) && apply_drive_fault(name, v, s)) return Status{Ok{}};
    return make_error("--fault " + spec + ": not a fault of a CiA 402 drive, or wrong values\n" +
                      kFaultHelp);
  }
  stand::DeviceClock* clock = nullptr;
  if (name == "clock-jump") {
    const std::size_t c = value.find(':');
    const std::string dev = value.substr(0, c);
    clock = dev == "ins" ? &s.ins_clock : dev == "table" ? &s.table_clock : nullptr;
    if (clock == nullptr || c == std::string::npos)
      return make_error("--fault clock-jump=ins|table:AT:SECONDS, not '" + value + "'");
    value = value.substr(c + 1);
  }
  // AT as turn+S: S stand seconds after the table first turns
  const bool from_turn = value.starts_with("turn+");
  if (from_turn && name != "ins-silent" && name != "encoder-silent")
    return make_error("--fault " + spec + ": only ins-silent and encoder-silent take turn+S");
  if (from_turn) value = value.substr(5);
  std::vector<double> v;
  if (!numbers(value, v)) return make_error("--fault " + spec + ": expected numbers after '='");
  if (from_turn && v[0] < 0)
    return make_error("--fault " + spec + ": turn+S takes S of 0 or more seconds");
  auto want = [&](std::size_t lo, std::size_t hi) { return v.size() >= lo && v.size() <= hi; };
  auto& f = s.faults;
  if (name == "ins-drop" && want(1, 1) && v[0] >= 0 && v[0] <= 1) {
    f.ins_drop_rate = v[0];
  } else if (name == "ins-spikes" && want(1, 1) && v[0] >= 0 && v[0] <= 1) {
    f.ins_spike_rate = v[0];
  } else if (name == "ins-burst" && want(2, 2)) {
    f.ins_burst_at_s = v[0];
    f.ins_burst_s = v[1];
  } else if (name == "ins-silent" && want(1, 1)) {
    (from_turn ? f.ins_silent_after_turn_s : f.ins_silent_at_s) = v[0];
  } else if (name == "ins-fault" && want(1, 1)) {
    s.ins.fault_at_s = v[0];
  } else if (name == "encoder-silent" && want(1, 1)) {
    (from_turn ? f.encoder_silent_after_turn_s : f.encoder_silent_at_s) = v[0];
  } else if (name == "table-stall" && want(1, 1)) {
    s.table_faults.stall_after_s = v[0];
  } else if (name == "table-overshoot" && want(1, 1) && v[0] >= 0) {
    s.table_faults.overshoot_rad = v[0] * kDeg;
  } else if (name == "table-fault" && want(1, 1)) {
    s.table_faults.drive_fault_at_s = v[0];
  } else if (name == "table-off-target" && want(1, 1)) {
    s.table_faults.off_target_rad = v[0] * kDeg;
  } else if (name == "table-drift" && want(2, 2)) {
    s.table_faults.drift_at_s = v[0];
    s.table_faults.drift_rad = v[1] * kDeg;
  } else if (name == "garbage" && want(1, 1) && v[0] >= 0) {
    f.garbage_rate_hz = v[0];
  } else if (name == "flood" && want(2, 3)) {
    f.flood_at_s = v[0];
    f.flood_s = v[1];
    if (v.size() == 3) f.flood_rate_hz = v[2];
  } else if (clock != nullptr && want(2, 2)) {
    clock->jump_at_s = v[0];
    clock->jump_s = v[1];
  } else {
    return make_error("--fault " + spec + ": unknown fault or wrong values\n" + kFaultHelp);
  }
  return Status{Ok{}};
}

Status apply_clock(const std::string& opt, const std::string& spec, stand::DeviceClock& c) {
  std::vector<double> v;
  if (spec.empty()) return Status{Ok{}};
  if (!numbers(spec, v) || v.size() != 2)
    return make_error(opt + ": expected OFFSET_SECONDS:RATE_PPM, not '" + spec + "'");
  c.offset_s = v[0];
  c.rate_ppm = v[1];
  return Status{Ok{}};
}

/// --rates: lower frame rates for a slow host (the ICD's are the default).
Status apply_rates(const std::string& spec, stand::StandSetup& s) {
  if (spec.empty()) return Status{Ok{}};
  std::vector<double> v;
  const auto bad = [&] {
    return make_error(
        "--rates: expected VEL_HZ:ENC_HZ[:INS_STATUS_HZ:TABLE_STATUS_HZ], all above 0, "
        "VEL_HZ dividing the IMU rate, not '" +
        spec + "'");
  };
  if (!numbers(spec, v) || (v.size() != 2 && v.size() != 4)) return bad();
  for (double r : v)
    if (!(r > 0) || r > s.ins.sim.imu_rate_hz) return bad();
  const double div = s.ins.sim.imu_rate_hz / v[0];
  if (std::abs(div - std::round(div)) > 1e-9) return bad();
  s.ins.sim.output_rate_hz = v[0];
  s.encoder_hz = v[1];
  if (v.size() == 4) {
    s.ins_status_hz = v[2];
    s.table_status_hz = v[3];
  }
  return Status{Ok{}};
}

int usage(const char* why) {
  if (why != nullptr) std::fprintf(stderr, "turncal-sim: %s\n", why);
  std::fprintf(stderr,
               "usage: turncal-sim [--speed N] [--scripted-host] [--truth TRUTH.json]\n"
               "                   [--state-out STATE.json] [common]\n"
               "        (--state-out: the table's state, the host frames and the heartbeat's\n"
               "        gaps as the stand saw them, written when it stops)\n"
               "        [--real-bus] (send on a CAN interface that is not virtual: without\n"
               "        it, only vcan and vxcan; a simulator never puts its encoder on a\n"
               "        real stand's bus by mistake)\n"
               "       turncal-sim --offline --out RUN.log --truth TRUTH.json [common]\n"
               "common: [--profile PLAN.toml] [--config turncal.toml] [--seed N]\n"
               "        [--heading-offset DEG] [--ins-interface IF] [--table-interface IF]\n"
               "        [--fault NAME=VALUE]... [--drive NAME[=VALUE]]...\n"
               "        [--ins-clock OFFSET_S:PPM]\n"
               "        [--table-clock OFFSET_S:PPM] [--truth-in ERRORS.json]\n"
               "        [--angle-limits MIN_DEG:MAX_DEG] (the table's soft limits)\n"
               "        [--table-heartbeat-timeout S] (the table stops itself after S stand\n"
               "        seconds without a host heartbeat while it moves; default 0.5, and\n"
               "        live at --speed N above 1, N times [stand] real_time_floor_ms more)\n"
               "        [--rates VEL_HZ:ENC_HZ[:INS_STATUS_HZ:TABLE_STATUS_HZ]] (frame rates;\n"
               "        default 100:200:10:20; VEL_HZ must divide the 400 Hz IMU rate)\n"
               "        [--start-time UNIX_S] (offline only)\n%s",
               kFaultHelp);
  return 2;
}

bool parse(int argc, char** argv, Options& o, std::string& err) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> const char* {
      if (i + 1 >= argc) {
        err = a + " needs a value";
        return nullptr;
      }
      return argv[++i];
    };
    auto number = [&](double& out) {
      const char* v = value();
      if (v == nullptr) return false;
      char* end = nullptr;
      out = std::strtod(v, &end);
      if (end == v || *end != '\0') {
        err = a + ": '" + v + "' is not a number";
        return false;
      }
      return true;
    };
    if (a == "--offline") {
      o.offline = true;
    } else if (a == "--scripted-host") {
      o.scripted_host = true;
    } else if (a == "--real-bus") {
      o.real_bus = true;
    } else if (a == "--fault" || a == "--drive" || a == "--ins-clock" || a == "--table-clock" ||
               a == "--truth-in" || a == "--angle-limits" || a == "--rates" ||
               a == "--table-heartbeat-timeout") {
      const char* v = value();
      if (v == nullptr) return false;
      if (a == "--fault")
        o.faults.emplace_back(v);
      else if (a == "--drive")
        o.drive_ways.emplace_back(v);
      else
        (a == "--ins-clock"      ? o.ins_clock
         : a == "--table-clock"  ? o.table_clock
         : a == "--truth-in"     ? o.truth_in
         : a == "--rates"        ? o.rates
         : a == "--angle-limits" ? o.angle_limits
                                 : o.heartbeat_timeout) = v;
    } else if (a == "--out" || a == "--truth" || a == "--profile" || a == "--config" ||
               a == "--ins-interface" || a == "--table-interface" || a == "--state-out") {
      const char* v = value();
      if (v == nullptr) return false;
      std::string& dst = a == "--out"             ? o.out
                         : a == "--state-out"     ? o.state_out
                         : a == "--truth"         ? o.truth
                         : a == "--profile"       ? o.profile
                         : a == "--config"        ? o.config
                         : a == "--ins-interface" ? o.ins_interface
                                                  : o.table_interface;
      dst = v;
    } else if (a == "--speed") {
      if (!number(o.speed)) return false;
      if (!(o.speed > 0) || o.speed > 10000) {
        err = "--speed: expected a factor above 0, at most 10000";
        return false;
      }
    } else if (a == "--seed") {
      double s = 0;
      if (!number(s) || s < 0 || s != std::floor(s)) {
        if (err.empty()) err = "--seed: expected a non-negative integer";
        return false;
      }
      o.seed = static_cast<std::uint64_t>(s);
    } else if (a == "--heading-offset") {
      if (!number(o.heading_offset_deg)) return false;
    } else if (a == "--start-time") {
      if (!number(o.start_time_s)) return false;
    } else if (a == "--help" || a == "-h") {
      err = "";
      return false;
    } else {
      err = "unknown option " + a;
      return false;
    }
  }
  return true;
}

nlohmann::json truth_json(const sim::Config& c, const Plan& plan, const Options& o) {
  using nlohmann::json;
  json e = json::object();
  const est::ParamArray p = est::params_of(c.errors);
  for (std::size_t k = 0; k < p.size(); ++k) e[std::string(est::kParamNames[k])] = p[k];
  const double g = earth::normal_gravity(c.latitude_rad, c.height_m);
  e["df_eff_1"] = c.errors.df0(0) + g * c.errors.g(0);
  e["df_eff_2"] = c.errors.df0(1) + g * c.errors.g(1);
  return json{{"units", "SI: rad/s, rad, m/s^2, m, m/s, 1"},
              {"seed", o.seed},
              {"profile", plan.source},
              {"site", {{"latitude_rad", c.latitude_rad}, {"height_m", c.height_m}}},
              {"heading_offset_rad", o.heading_offset_deg * kDeg},
              {"errors", e},
              {"start",
               {{"v0_east_mps", c.start.v0(0)},
                {"v0_north_mps", c.start.v0(1)},
                {"dr_east_m", c.start.dr_e_m},
                {"dr_north_m", c.start.dr_n_m},
                {"dpsi0_rad", c.start.dpsi0_rad}}},
              {"noise",
               {{"arw_rad_per_rts", c.noise.arw},
                {"vrw_mps_per_rts", c.noise.vrw},
                {"velocity_mps", c.noise.velocity_sigma}}}};
}

/// Errors given in a file, in the truth file's own form ("errors": model.md's
/// names; "start": the start errors); what it leaves out stays as drawn.
Status read_truth(const std::string& path, sim::Config& c) {
  std::ifstream in(path);
  if (!in) return make_error("cannot open the errors file", SourcePos{path, 0, 0});
  nlohmann::json j;
  try {
    in >> j;
  } catch (const nlohmann::json::exception& e) {
    return make_error(e.what(), SourcePos{path, 0, 0});
  }
  const nlohmann::json e = j.value("errors", nlohmann::json::object());
  est::ParamArray p = est::params_of(c.errors);
  for (const auto& [key, val] : e.items()) {
    if (key == "df_eff_1" || key == "df_eff_2") continue;  // derived
    const int k = est::param_index(key);
    if (k < 0)
      return make_error("unknown error '" + key + "' (model.md's names)", SourcePos{path, 0, 0});
    if (!val.is_number())
      return make_error("error '" + key + "': expected a number", SourcePos{path, 0, 0});
    p[static_cast<std::size_t>(k)] = val.get<double>();
  }
  c.errors = est::sensor_errors(p);
  const nlohmann::json st = j.value("start", nlohmann::json::object());
  c.start.v0(0) = st.value("v0_east_mps", c.start.v0(0));
  c.start.v0(1) = st.value("v0_north_mps", c.start.v0(1));
  c.start.dr_e_m = st.value("dr_east_m", c.start.dr_e_m);
  c.start.dr_n_m = st.value("dr_north_m", c.start.dr_n_m);
  c.start.dpsi0_rad = st.value("dpsi0_rad", c.start.dpsi0_rad);
  return Status{Ok{}};
}

/// What both modes need: the plan, the stand's configuration and the
/// stand's setup with the truth drawn from the seed.
struct World {
  Plan plan;
  Config cfg;
  can::Database db;
  stand::StandSetup setup;
};

Result<World> load_world(const Options& o) {
  World w;
  TURNCAL_ASSIGN(plan, load_plan(o.profile));
  w.plan = std::move(plan);
  TURNCAL_ASSIGN(cfg, load_config(o.config));
  w.cfg = std::move(cfg);
  if (!o.ins_interface.empty()) w.cfg.can.ins_interface = o.ins_interface;
  if (!o.table_interface.empty()) w.cfg.can.table_interface = o.table_interface;
  TURNCAL_ASSIGN(db, load_databases(w.cfg.can));
  w.db = std::move(db);
  stand::StandSetup& setup = w.setup;
  setup.ins.sim = stand::draw_truth(w.plan, o.seed);
  setup.ins.heading_offset_rad = o.heading_offset_deg * kDeg;
  setup.table_angle0_rad = w.plan.start_angle_rad;
  if (!w.plan.profile.turns.empty()) {
    setup.table_limits.max_accel_rps2 = w.plan.profile.turns[0].max_accel_rps2;
    for (const TurnSpec& t : w.plan.profile.turns)
      setup.table_limits.max_rate_rps = std::max(setup.table_limits.max_rate_rps, t.max_rate_rps);
  }
  setup.seed = o.seed;
  setup.ins_layout = w.cfg.can.ins;
  if (w.cfg.can.table.is_cia402()) {
    // the table is a CiA 402 drive of the configured node and scale
    const Cia402Settings& c = w.cfg.can.table.cia402;
    setup.cia402 = true;
    setup.drive.node_id = c.node_id;
    setup.drive.counts_per_rev = c.counts_per_revolution;
    setup.drive.gear_ratio = c.gear_ratio;
    setup.drive.counts_clockwise = c.counts_clockwise;
  }
  if (!o.truth_in.empty()) TURNCAL_TRY(read_truth(o.truth_in, setup.ins.sim));
  for (const std::string& f : o.faults) TURNCAL_TRY(apply_fault(f, setup));
  for (const std::string& way : o.drive_ways) TURNCAL_TRY(apply_drive_way(way, setup));
  TURNCAL_TRY(apply_clock("--ins-clock", o.ins_clock, setup.ins_clock));
  TURNCAL_TRY(apply_clock("--table-clock", o.table_clock, setup.table_clock));
  if (!o.angle_limits.empty()) {
    std::vector<double> v;
    if (!numbers(o.angle_limits, v) || v.size() != 2 || !(v[0] < v[1]))
      return make_error("--angle-limits: expected MIN_DEG:MAX_DEG with MIN < MAX, not '" +
                        o.angle_limits + "'");
    setup.table_limits.angle_min_rad = v[0] * kDeg;
    setup.table_limits.angle_max_rad = v[1] * kDeg;
  }
  if (!o.heartbeat_timeout.empty()) {
    std::vector<double> v;
    if (!numbers(o.heartbeat_timeout, v) || v.size() != 1 || !(v[0] > 0))
      return make_error("--table-heartbeat-timeout: expected seconds above 0, not '" +
                        o.heartbeat_timeout + "'");
    setup.table_limits.heartbeat_timeout_s = v[0];
  }
  TURNCAL_TRY(apply_rates(o.rates, setup));
  if (!o.truth.empty()) {
    std::ofstream tj(o.truth);
    tj << truth_json(setup.ins.sim, w.plan, o).dump(2) << "\n";
    if (!tj) return make_error("cannot write the truth file", SourcePos{o.truth, 0, 0});
  }
  return w;
}

int fail(const Error& e) {
  std::fprintf(stderr, "turncal-sim: %s\n", e.describe().c_str());
  return 1;
}

int offline(const Options& o) {
  auto w = load_world(o);
  if (!w) return fail(w.error());
  if (w->setup.cia402)
    return fail(make_error(
        "--offline scripts the reference table's host; a CiA 402 stand runs live, with turncald "
        "as its CANopen master"));
  // the roles point into the database: resolve them where it now lives
  auto roles = resolve_roles(w->cfg.can, w->db);
  if (!roles) return fail(roles.error());
  auto log = can::LogWriter::open(o.out);
  if (!log) return fail(log.error());
  const auto run =
      stand::run_offline(w->plan, w->cfg.can, w->db, *roles, w->setup, *log, o.start_time_s);
  if (!run) return fail(run.error());
  if (auto c = log->close(); !c) return fail(c.error());
  return 0;
}

volatile std::sig_atomic_t g_stop = 0;
extern "C" void on_signal(int) {
  g_stop = 1;
}

int live(const Options& o) {
  auto w = load_world(o);
  if (!w) return fail(w.error());
  // The table's own watchdog on the host's heartbeat is stand time: at N
  // times real time a stall of this machine is N times longer to it. As the
  // daemon's waits, it gets [stand] real_time_floor_ms of real time more
  // (none at 1x or slower; none to a timeout --table-heartbeat-timeout
  // gives, which is the stand's exactly).
  if (o.heartbeat_timeout.empty() && o.speed > 1)
    w->setup.table_limits.heartbeat_timeout_s += w->cfg.stand.real_time_floor_ms * 1e-3 * o.speed;
  auto roles = resolve_roles(w->cfg.can, w->db);
  if (!roles) return fail(roles.error());
  struct sigaction sa {};
  sa.sa_handler = on_signal;
  ::sigaction(SIGINT, &sa, nullptr);
  ::sigaction(SIGTERM, &sa, nullptr);

  // A simulator's encoder and INS frames on a real stand's bus would be
  // read as the real table's and the real INS's: only a virtual CAN bus,
  // unless told. A kind that cannot be read counts as real.
  for (const std::string& name : {w->cfg.can.ins_interface, w->cfg.can.table_interface}) {
    if (o.real_bus) break;
    if (Status v = socketcan::require_virtual_can(name); !v)
      return fail(make_error(v.error().describe() +
                             ": a simulated stand's frames on it would pass for the real "
                             "table's and INS's; give --real-bus to send on it all the same"));
  }
  // one socket per interface; the INS and the table may share one
  // receive stamps on the realtime clock at the start plus monotonic time:
  // a step of the wall clock (a host's test of one) moves no host frame
  socketcan::HostClock host_clock;
  std::vector<socketcan::Socket> sockets;
  for (const std::string& name : {w->cfg.can.ins_interface, w->cfg.can.table_interface}) {
    if (!sockets.empty() && sockets.front().interface() == name) break;
    socketcan::Options so;
    so.interface = name;
    so.error_frames = false;
    so.tx_queue_limit = 4096;
    so.require_virtual = !o.real_bus;  // on every re-open too
    so.clock = &host_clock;
    auto s = socketcan::Socket::open(so);
    if (!s) return fail(s.error());
    sockets.push_back(std::move(*s));
  }
  socketcan::Socket& ins_sock = sockets.front();
  socketcan::Socket& table_sock = sockets.back();
  stand::StandLoop loop(w->setup, w->db, *roles, o.scripted_host ? &w->plan : nullptr);
  std::fprintf(stderr,
               "turncal-sim: stand on %s (INS) and %s (table), speed %g%s, seed %llu; the table "
               "stops itself after %.3g s of stand time without the host's heartbeat\n",
               ins_sock.interface().c_str(), table_sock.interface().c_str(), o.speed,
               o.scripted_host ? ", scripted host" : "", static_cast<unsigned long long>(o.seed),
               w->setup.table_limits.heartbeat_timeout_s);

  using Clock = std::chrono::steady_clock;
  const auto wall0 = Clock::now();
  const std::int64_t kernel0_ns = host_clock.now_ns();  // the receive timestamps' clock
  std::vector<stand::StandFrame> frames;
  // Host frames wait for the tick of the stand time they arrived at (from
  // their kernel receive timestamps), so a stand that fell behind and
  // catches up sees the heartbeat as the bus carried it, not all at once.
  std::deque<std::pair<double, can::Frame>> from_bus;
  std::vector<can::Frame> due;
  socketcan::RxBatch rx;
  double max_lag_s = 0;
  // A CiA 402 drive's TPDO that would go out more than this late (real s)
  // is not sent: a real drive samples its position as it sends it, so the
  // host dates it to the bus's latency, by its receive time (event-driven)
  // or by the SYNC it answers (synchronous); a stand that fell behind real
  // time (its host stalled) and sent it late, in a burst, would date the
  // position by the stall (at 10x a guest's 150 ms stall put the turn 1.5 s
  // of the stand's time late, and the lever arm 13 sigma off), or answer a
  // SYNC after the next one went out. The host sees a TPDO missed instead;
  // but a late TPDO of a table at rest goes out (what it says is as true
  // at its receipt; one on SYNC only while the next SYNC has not gone out,
  // so it answers no other), so a stall of the stand in a hold does not
  // silence the drive as a fault would. (An answer to a SYNC over half a
  // period late is dated by its receipt and its SYNC counted unanswered:
  // such frames are counted too, as the drops the host may count.)
  constexpr double kReceiptSlackS = 0.001;
  // A TPDO answering a SYNC holds what the drive sampled at the SYNC: it
  // may go out later, as a real drive's waits for the bus, but not after
  // the host's next SYNC, which would date it. turncald queues no two
  // SYNCs within half a period (a full send queue could still put two
  // closer on the bus), and takes a TPDO1 within half a period after a
  // SYNC as its answer: 0.4 of the SYNC period, the median of the last
  // intervals between two SYNCs (stand s) or their mean if less, from the
  // SYNC's own time (the stand takes it up to a tick after), stays clear
  // of that (one pair sent close together changes no median). (A quarter,
  // as before, left a one-CPU guest 6 ms of real time at 4x, and a stall
  // of the stand longer than that lost ten answers in a row: the encoder
  // lost.)
  constexpr double kSyncSlack = 0.4;
  double sync_last_at = NAN;
  std::deque<double> sync_gaps;
  double sync_period = INFINITY;
  std::uint64_t late_tpdo_frames = 0;  // not sent
  std::uint64_t owed_heartbeats = 0;   // not sent: the stand was behind
  // answers to a SYNC that may reach the host past the half period it
  // dates an answer by its SYNC in (then by its receipt, the SYNC counted
  // unanswered): sent late all the same (at rest), or queued by the socket
  std::uint64_t late_sync_answers = 0;
  stand::VirtualDrive402* receipt_drive = loop.stand().drive();
  // The stand sleeps to the next tick in steps of whole milliseconds, as
  // poll(2) had them, so a fast stand runs its ticks in batches and does
  // not wake up for each (at 16x, sleeping to the microsecond woke it for
  // every tick and loaded a user-mode Linux guest); with a CiA 402 drive
  // to the microsecond, as a step's rounding up would send every TPDO up
  // to a step late.
  const double sleep_step_s = receipt_drive != nullptr ? 0.0 : 1e-3;
  // the host heartbeat as the table receives it (kernel receive times, stand s)
  const can::Message* hb = (*roles)[Role::HeartbeatCounter].message;
  double hb_last = NAN;
  std::vector<double> hb_gaps, hb_gap_ends;     // each gap, and when it ended (stand s)
  double hb_max_gap = 0, hb_max_gap_end = NAN;  // the longest gap, and when it ended (stand s)
  // the longest gap ending in a flood (--fault flood) or the 5 s after it
  const double flood_from = w->setup.faults.flood_at_s;
  const double flood_to = flood_from + w->setup.faults.flood_s + 5;
  double hb_max_gap_flood = 0;
  std::uint64_t hb_in_flood = 0;  // heartbeats received in that window
  // what the bus has for the stand, into from_bus (a host frame waits there
  // for its tick), the frames read before an error too; false on a socket's
  // error (kept in bus_error until the loop reports it). With `recover`, a
  // socket whose interface went away is re-opened when it is back; without
  // it (a look at what waits) it is left for the loop.
  std::optional<Error> bus_error;
  const auto read_bus = [&](bool recover) -> bool {
    if (bus_error) return false;
    for (socketcan::Socket& s : sockets) {
      rx.clear();
      if (s.fd() < 0) {
        if (recover) s.try_recover(rx);
        continue;
      }
      auto got = s.receive(rx);
      if (!got) bus_error = got.error();
      for (const can::TimedFrame& f : rx.frames) {
        const double at = static_cast<double>(f.time_ns - kernel0_ns) * 1e-9 * o.speed;
        from_bus.emplace_back(at, f.frame);
        if (stand::facts::is_sync(f.frame)) {
          if (!std::isnan(sync_last_at) && at > sync_last_at) {
            sync_gaps.push_back(at - sync_last_at);
            if (sync_gaps.size() > 15) sync_gaps.pop_front();
            std::vector<double> g(sync_gaps.begin(), sync_gaps.end());
            std::nth_element(g.begin(), g.begin() + static_cast<std::ptrdiff_t>(g.size() / 2),
                             g.end());
            // nor more than their mean: gaps that alternate (a period no
            // whole number of the host's ticks) have the long one as median
            const double mean =
                std::accumulate(g.begin(), g.end(), 0.0) / static_cast<double>(g.size());
            sync_period = std::min(g[g.size() / 2], mean);
          }
          sync_last_at = at;
        }
        if (hb != nullptr && f.frame.id == hb->id && f.frame.extended == hb->extended) {
          if (!std::isnan(hb_last)) {
            if (at - hb_last > hb_max_gap) {
              hb_max_gap = at - hb_last;
              hb_max_gap_end = at;
            }
            if (at >= flood_from && at <= flood_to) {
              hb_max_gap_flood = std::max(hb_max_gap_flood, at - hb_last);
              ++hb_in_flood;
            }
            hb_gaps.push_back(at - hb_last);
            hb_gap_ends.push_back(at);
          }
          hb_last = at;
        }
      }
      if (bus_error) return false;
    }
    return true;
  };
  // whether the last read_bus took all that waits on every socket
  const auto bus_drained = [&] {
    return std::all_of(sockets.begin(), sockets.end(),
                       [](const socketcan::Socket& s) { return s.fd() >= 0 && s.drained(); });
  };
  // the stand times of the last tick that took a frame commanding the
  // drive, and of the last that took a SYNC (and how many it took)
  double command_taken_t = -INFINITY;
  double sync_taken_t = -INFINITY;
  int syncs_taken_then = 0;
  while (g_stop == 0 && !loop.done()) {
    if (!read_bus(true)) return fail(*bus_error);
    const double target = std::chrono::duration<double>(Clock::now() - wall0).count() * o.speed;
    // how far behind real time the stand fell (its frames then go out late, in a burst)
    max_lag_s = std::max(max_lag_s, (target - loop.next_time()) / o.speed);
    double real_s = target / o.speed;  // with a CiA 402 drive read again each tick
    while (loop.next_time() <= target && !loop.done()) {
      while (!from_bus.empty() && from_bus.front().first <= loop.next_time()) {
        due.push_back(from_bus.front().second);
        from_bus.pop_front();
      }
      if (receipt_drive != nullptr) {
        const double t = loop.next_time();
        for (const can::Frame& c : due) {
          if (receipt_drive->commanded_by(c)) command_taken_t = t;
          if (stand::facts::is_sync(c)) {
            syncs_taken_then = sync_taken_t == t ? syncs_taken_then + 1 : 1;
            sync_taken_t = t;
          }
        }
      }
      loop.tick(due, frames);
      due.clear();
      if (receipt_drive != nullptr)
        real_s = std::chrono::duration<double>(Clock::now() - wall0).count();
      for (const stand::StandFrame& f : frames) {
        // how late it goes out: now, against the stand time it is due
        const auto slack = [&] {
          return receipt_drive->event_driven() || !std::isfinite(sync_period)
                     ? kReceiptSlackS
                     : std::max(kReceiptSlackS,
                                (sync_period * kSyncSlack - stand::StandLoop::kTick) / o.speed);
        };
        // a TPDO of a table at rest goes out late if what it says is as
        // true at its receipt (stand::still_true_late)
        const bool on_sync = receipt_drive != nullptr && !receipt_drive->event_driven();
        const auto still_true = [&] {
          stand::LateTpdo l;
          l.t_s = f.t_s;
          l.at_rest = !receipt_drive->moving(f.t_s);
          l.on_sync = on_sync;
          l.scripted_host = o.scripted_host;
          l.command_taken_t = command_taken_t;
          l.sync_taken_t = sync_taken_t;
          l.syncs_taken_then = syncs_taken_then;
          l.stand_tx_waiting = table_sock.tx_pending();
          // an error is the loop's to report, at its next turn
          l.bus_read = read_bus(false) && bus_drained();
          for (const auto& waiting : from_bus) {
            l.command_waiting = l.command_waiting || receipt_drive->commanded_by(waiting.second);
            l.sync_waiting = l.sync_waiting || stand::facts::is_sync(waiting.second);
          }
          return stand::still_true_late(l);
        };
        // a heartbeat the stand owed while behind real time: the later
        // one, due before the time this catch-up runs to, goes instead
        // (VirtualDrive402::owed_heartbeat); the last one due always goes
        if (receipt_drive != nullptr && !f.ins_side &&
            receipt_drive->owed_heartbeat(f.frame, target - f.t_s)) {
          ++owed_heartbeats;
          continue;
        }
        const bool timed =
            receipt_drive != nullptr && !f.ins_side && receipt_drive->timed_on_the_bus(f.frame);
        bool late = false;
        if (timed && real_s - f.t_s / o.speed > slack()) {
          if (!still_true()) {
            ++late_tpdo_frames;
            receipt_drive->unsent(f.frame);
            continue;
          }
          late = true;
        }
        auto sent = (f.ins_side ? ins_sock : table_sock).send(f.frame);
        if (!sent) return fail(sent.error());  // a frame the socket cannot carry
        // every such answer counted, not only those the stand's clock puts
        // past half its own estimate of the period: the host's period and
        // clock are its own
        if (on_sync && timed && (late || *sent == socketcan::TxOutcome::Queued))
          ++late_sync_answers;
      }
      frames.clear();
    }
    for (socketcan::Socket& s : sockets) s.flush();
    // sleep until the next tick is due, or a host frame arrives (from now:
    // the batch took time)
    const double wait_s =
        loop.next_time() / o.speed - std::chrono::duration<double>(Clock::now() - wall0).count();
    std::vector<pollfd> fds;
    for (socketcan::Socket& s : sockets)
      if (s.fd() >= 0)
        fds.push_back({s.fd(), static_cast<short>(POLLIN | (s.tx_pending() ? POLLOUT : 0)), 0});
    const double sleep_s =
        sleep_step_s > 0 ? std::ceil(wait_s / sleep_step_s) * sleep_step_s : wait_s;
    const auto wait_ns = static_cast<long long>(std::max(0.0, std::ceil(sleep_s * 1e9)));
    const timespec wait_ts{static_cast<time_t>(wait_ns / 1'000'000'000),
                           static_cast<long>(wait_ns % 1'000'000'000)};
    ::ppoll(fds.data(), fds.size(), &wait_ts, nullptr);
  }
  if (const Error* e = loop.error()) return fail(*e);
  const auto& c = loop.stand().counts();
  // what the stand's sockets counted, summed over them
  const auto bus_stat = [&](std::uint64_t socketcan::Stats::*field) {
    std::uint64_t n = 0;
    for (const socketcan::Socket& sock : sockets) n += sock.stats().*field;
    return n;
  };
  if (!o.state_out.empty()) {
    // what the stand itself says at the end: what a test of the host's
    // faults checks (did the table stop, did our quick stop reach it)
    const double now = loop.next_time();
    // the heartbeat's gaps more than 20% off their mean (the host's period)
    double mean_gap = 0;
    for (const double g : hb_gaps) mean_gap += g / static_cast<double>(hb_gaps.size());
    std::uint64_t off = 0;
    std::uint64_t off_half = 0;                            // more than half a period off
    nlohmann::json off_half_at = nlohmann::json::array();  // the first 50: when they ended
    for (std::size_t i = 0; i < hb_gaps.size(); ++i) {
      const double g = hb_gaps[i];
      off += std::abs(g - mean_gap) > 0.2 * mean_gap;
      if (std::abs(g - mean_gap) > 0.5 * mean_gap) {
        ++off_half;
        if (off_half_at.size() < 50) off_half_at.push_back({hb_gap_ends[i], g});
      }
    }
    const auto st = loop.stand().table().status(now);
    nlohmann::json drive = nullptr;
    if (const stand::VirtualDrive402* d = loop.stand().drive()) {
      // the CiA 402 drive's own state: what a test of the host's faults checks
      drive = {{"state", std::string(stand::facts::state_name(d->state()))},
               {"statusword", d->statusword()},
               {"nmt", static_cast<int>(d->nmt())},
               {"angle_deg", d->angle(now) / kDeg},
               {"moving", d->moving(now)},
               {"emcy", d->emcy_sent()},
               {"quick_stops", d->counts().quick_stops},
               {"coasts", d->counts().coasts},
               {"host_heartbeat_lost", d->counts().host_heartbeat_lost},
               {"set_points", d->counts().set_points},
               {"tpdos", d->counts().tpdo},
               {"tpdo_frames_not_sent_late", late_tpdo_frames},
               {"owed_heartbeats_not_sent", owed_heartbeats},
               {"sync_answer_frames_late_or_queued", late_sync_answers}};
    }
    const nlohmann::json j = {
        {"drive", drive},
        {"stand_time_s", now},
        {"table",
         {{"state", static_cast<int>(st.state)},
          {"fault", static_cast<int>(st.fault)},
          {"rate_dps", st.rate_rps / kDeg},
          {"angle_deg", loop.stand().table().angle(now) / kDeg}}},
        // what the stand's own sockets lost (a host frame it never read,
        // a frame of its it never sent)
        {"bus",
         {{"rx_dropped", bus_stat(&socketcan::Stats::rx_dropped)},
          {"tx_overflow", bus_stat(&socketcan::Stats::tx_overflow)},
          {"tx_failed", bus_stat(&socketcan::Stats::tx_failed)}}},
        {"counts",
         {{"host_frames", c.host_frames},
          {"host_undecodable", c.host_undecodable},
          {"table_commands", c.table_commands},
          {"quick_stops", c.quick_stops},
          {"refused", c.refused},
          {"heartbeats", c.heartbeats}}},
        {"heartbeat",
         {{"gaps", hb_gaps.size()},
          {"mean_gap_s", mean_gap},
          {"max_gap_s", hb_max_gap},
          {"max_gap_end_s", hb_max_gap_end},
          {"max_gap_in_flood_s",
           std::isnan(flood_from) ? nlohmann::json(nullptr) : nlohmann::json(hb_max_gap_flood)},
          {"in_flood",
           std::isnan(flood_from) ? nlohmann::json(nullptr) : nlohmann::json(hb_in_flood)},
          {"flood_window_s", std::isnan(flood_from) ? nlohmann::json(nullptr)
                                                    : nlohmann::json({flood_from, flood_to})},
          {"gaps_off_20_percent", off},
          {"gaps_off_50_percent", off_half},
          {"gaps_off_50_percent_end_and_length_s", off_half_at}}}};
    std::ofstream f(o.state_out);
    f << j.dump(2) << "\n";
    f.close();
    if (!f) return fail(make_error("cannot write " + o.state_out));
  }
  // an error met while looking at the bus in the last turn, then stopped
  // (the state file written first: what a test reads, beside this error)
  if (bus_error) return fail(*bus_error);
  const std::uint64_t overflow = bus_stat(&socketcan::Stats::tx_overflow);
  std::fprintf(stderr,
               "turncal-sim: stopped at %.3f s simulated; host frames %llu (undecodable %llu, "
               "refused commands %llu); send queue overflow %llu; at most %.0f ms behind real "
               "time; drive TPDO frames not sent as late (over %.0f ms, on SYNC over %.2f of its "
               "period) %llu; answers on SYNC sent late at rest or queued %llu; drive heartbeats "
               "owed while behind, not sent %llu\n",
               loop.next_time(), static_cast<unsigned long long>(c.host_frames),
               static_cast<unsigned long long>(c.host_undecodable),
               static_cast<unsigned long long>(c.refused),
               static_cast<unsigned long long>(overflow), max_lag_s * 1e3, kReceiptSlackS * 1e3,
               kSyncSlack, static_cast<unsigned long long>(late_tpdo_frames),
               static_cast<unsigned long long>(late_sync_answers),
               static_cast<unsigned long long>(owed_heartbeats));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  std::string err;
  if (!parse(argc, argv, o, err)) return usage(err.empty() ? nullptr : err.c_str());
  if (!o.offline) return live(o);
  if (o.out.empty() || o.truth.empty()) return usage("--offline needs --out and --truth");
  return offline(o);
}
