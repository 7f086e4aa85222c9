// turncalctl's offline commands: they need no daemon.
//
//   replay LOG [--config FILE] [--report LIVE.json | --no-report]
//              [--profile PLAN.toml] [--set KEY=VALUE]... [--epoch S]
//              [--mean | --sample] [--two-stage | --no-two-stage]
//              [--second-pass auto|off|always]
//              [--heading-offset DEG] [--json OUT] [--html OUT] [--truth TRUTH.json]
//   plan [--config FILE] [--profile PLAN.toml | --compare PLAN.toml...] [--set KEY=VALUE]...
//   [--epoch S]
//        [--mean | --sample] [--heading-offset DEG] [--rate HZ] [--no-sweep]
//        [--json OUT]
//   check [--config FILE] [--profile PLAN.toml]
//   dbc FILE.dbc
//   decode FILE.dbc LOG [--json]
#include "offline.hpp"
#include "turncal/build_paths.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <numbers>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "turncal/can/candump.hpp"
#include "turncal/can/dbc.hpp"
#include "turncal/config.hpp"
#include "turncal/drivers/reference.hpp"
#include "turncal/run/engine.hpp"
#include "turncal/run/planning.hpp"
#include "turncal/run/replay.hpp"
#include "turncal/run/report.hpp"

namespace turncal::ctl {

using nlohmann::json;
namespace fs = std::filesystem;

namespace {

std::string default_config() {
  if (const char* e = std::getenv("TURNCAL_CONFIG")) return e;
  return std::string(turncal::build::data_dir) + "/turncal.toml";
}

/// The INS's output on a stand: the coarser step of its two velocity
/// signals (which limits the estimate), and its rate.
run::InsOutput ins_output_of(const RoleMap& roles, double rate_hz) {
  run::InsOutput o;
  for (const Role r : {Role::InsVelEast, Role::InsVelNorth}) {
    const can::Signal& sig = *roles[r].signal;
    const double step = std::abs(sig.factor) * velocity_unit(sig).value();
    if (step > o.resolution_mps) {
      o.resolution_mps = step;
      o.signal = roles[r].message->name + "." + sig.name;
    }
  }
  o.rate_hz = rate_hz;
  return o;
}

bool read_json(const std::string& path, json& out) {
  std::ifstream in(path);
  if (!in) return false;
  out = json::parse(in, nullptr, false);
  return !out.is_discarded() && out.is_object();
}

/// Writes text to a file, or says why not.
bool write_text(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
  out.close();
  if (!out) std::fprintf(stderr, "turncalctl: cannot write %s\n", path.c_str());
  return static_cast<bool>(out);
}

/// True when `r` holds a value; else says its error (a configuration's
/// names file, line and key) and is false.
template <class T>
bool or_say(const Result<T>& r) {
  if (!r) std::fprintf(stderr, "turncalctl: %s\n", r.error().describe().c_str());
  return static_cast<bool>(r);
}

bool number(const char* s, double& v) {
  char* end = nullptr;
  v = std::strtod(s, &end);
  return end != s && *end == '\0';
}

/// The options replay and plan share: the configuration, the plan and its
/// overrides (--set, and the short forms --epoch, --mean, --sample), the
/// heading offset, the JSON output.
struct SharedOptions {
  std::string config = default_config();
  std::string profile;
  std::vector<std::string> overrides;
  std::optional<double> heading_offset_rad;
  std::string json_out;
};

/// True when argv[i] was a shared option (i moved past its value); `bad`
/// says why its value is not one.
bool shared_option(int argc, char** argv, int& i, SharedOptions& o, std::string& bad) {
  const std::string a = argv[i];
  const bool has = i + 1 < argc;
  double v = 0;
  if (a == "--config" && has) {
    o.config = argv[++i];
  } else if (a == "--profile" && has) {
    o.profile = argv[++i];
  } else if (a == "--set" && has) {
    o.overrides.emplace_back(argv[++i]);
  } else if (a == "--epoch" && has) {
    if (!number(argv[++i], v)) bad = "--epoch needs seconds";
    o.overrides.push_back("estimation.epoch_s=" + std::string(argv[i]));
  } else if (a == "--mean" || a == "--sample") {
    o.overrides.push_back("estimation.measurement=\"" + a.substr(2) + "\"");
  } else if (a == "--heading-offset" && has) {
    if (!number(argv[++i], v)) bad = "--heading-offset needs degrees";
    o.heading_offset_rad = v * std::numbers::pi / 180;
  } else if (a == "--json" && has) {
    o.json_out = argv[++i];
  } else {
    return false;
  }
  return true;
}

}  // namespace

int replay(int argc, char** argv, int i, bool as_json) {
  if (i >= argc) return usage("replay: missing LOG");
  const std::string log = argv[i++];
  std::string report_path, html_out, truth_path;
  bool no_report = false;
  SharedOptions so;
  run::ReplayOptions o;
  for (; i < argc; ++i) {
    const std::string a = argv[i];
    const bool has = i + 1 < argc;
    if (std::string bad; shared_option(argc, argv, i, so, bad)) {
      if (!bad.empty()) return usage(("replay: " + bad).c_str());
    } else if (a == "--report" && has) {
      report_path = argv[++i];
    } else if (a == "--no-report") {
      no_report = true;
    } else if (a == "--two-stage" || a == "--no-two-stage") {
      o.two_stage = a == "--two-stage";
    } else if (a == "--second-pass" && has) {
      const std::string m = argv[++i];
      using Mode = est::SecondPassSettings::Mode;
      if (m == "auto")
        o.second_pass = Mode::Auto;
      else if (m == "off")
        o.second_pass = Mode::Off;
      else if (m == "always")
        o.second_pass = Mode::Always;
      else
        return usage("replay: --second-pass needs auto, off or always");
    } else if (a == "--html" && has) {
      html_out = argv[++i];
      o.html = true;
    } else if (a == "--truth" && has) {
      truth_path = argv[++i];
    } else {
      return usage(("replay: unknown argument " + a).c_str());
    }
  }
  o.profile = so.profile;
  o.overrides = so.overrides;
  o.heading_offset_rad = so.heading_offset_rad;
  auto cfg = load_config(so.config);
  if (!or_say(cfg)) return kUsage;
  auto db = load_databases(cfg->can);
  if (!or_say(db)) return kUsage;
  auto roles = resolve_roles(cfg->can, *db);
  if (!or_say(roles)) return kUsage;
  // the live run's report: named, or next to the log as the daemon keeps it
  json live;
  if (!no_report) {
    if (report_path.empty()) {
      const fs::path beside = fs::path(log).replace_extension(".report.json");
      if (fs::exists(beside)) report_path = beside.string();
    }
    if (!report_path.empty()) {
      if (!read_json(report_path, live)) {
        std::fprintf(stderr, "turncalctl: %s: not a turncal report\n", report_path.c_str());
        return kUsage;
      }
      if (const std::string why = run::check_report(live); !why.empty()) {
        std::fprintf(stderr, "turncalctl: %s: unreadable report: %s\n", report_path.c_str(),
                     why.c_str());
        return kUsage;
      }
      if (!live.contains("profile") || !live["profile"].contains("toml")) {
        std::fprintf(stderr,
                     "turncalctl: %s has no profile to replay with (an interrupted run's "
                     "report?): give --profile or --no-report\n",
                     report_path.c_str());
        return kUsage;
      }
      std::fprintf(stderr, "turncalctl: replaying with the settings of %s\n", report_path.c_str());
      // The frames are read by the configuration given here (its DBC, its
      // roles, its INS layout), not by the one the run recorded with: say
      // so when they differ, or a changed layout reads other numbers.
      const std::string recorded = live.contains("config") && live["config"].is_object()
                                       ? live["config"].value("sha256", std::string())
                                       : std::string();
      const auto here = run::sha256_file(cfg->source.string());
      if (!recorded.empty() && here.ok() && here->sha256 != recorded)
        std::fprintf(stderr,
                     "turncalctl: warning: the run was recorded with the configuration %s "
                     "(sha256 %.12s...), this replay reads its frames by %s (sha256 %.12s...), "
                     "which differs: its DBC, roles and [ins] layout apply\n",
                     live["config"].value("file", std::string("?")).c_str(), recorded.c_str(),
                     cfg->source.string().c_str(), here->sha256.c_str());
    }
  }
  json truth;
  if (!truth_path.empty() && (!read_json(truth_path, truth) || !truth.contains("errors"))) {
    std::fprintf(stderr, "turncalctl: %s: not a turncal-sim truth file\n", truth_path.c_str());
    return kUsage;
  }
  auto r = run::replay_log(*cfg, *db, *roles, log, live.is_null() ? nullptr : &live, o);
  if (!or_say(r)) return kRefused;
  if (!so.json_out.empty() && !write_text(so.json_out, r->report.dump(2) + "\n")) return kRefused;
  if (!html_out.empty() && !write_text(html_out, r->html)) return kRefused;
  if (as_json)
    std::printf("%s\n", r->report.dump(2).c_str());
  else
    std::printf("%s", run::report_text(r->report, truth.is_null() ? nullptr : &truth).c_str());
  if (r->damage)
    std::fprintf(stderr, "turncalctl: %s: damaged at line %llu: %s\n", log.c_str(),
                 static_cast<unsigned long long>(r->damage->line), r->damage->what.c_str());
  for (const std::string& m : r->missing)
    std::fprintf(stderr, "turncalctl: %s: no frames of %s\n", log.c_str(), m.c_str());
  const bool done = r->report.value("status", std::string()) == "done";
  return done && !r->damage ? kOk : kRefused;
}

int plan(int argc, char** argv, int i, bool as_json) {
  SharedOptions so;
  run::PlanningSettings ps;
  std::vector<std::string> compare;
  for (; i < argc; ++i) {
    const std::string a = argv[i];
    const bool has = i + 1 < argc;
    double v = 0;
    if (std::string bad; shared_option(argc, argv, i, so, bad)) {
      if (!bad.empty()) return usage(("plan: " + bad).c_str());
    } else if (a == "--compare") {
      // the plans up to the next option
      while (i + 1 < argc && std::string(argv[i + 1]).rfind("--", 0) != 0)
        compare.emplace_back(argv[++i]);
      if (compare.size() < 2) return usage("plan: --compare needs two or more PLAN.toml");
    } else if (a == "--rate" && has) {
      if (!number(argv[++i], v) || !(v > 0)) return usage("plan: --rate needs the INS rate in Hz");
      ps.sample_rate_hz = v;
    } else if (a == "--no-sweep") {
      ps.sweep = false;
    } else {
      return usage(("plan: unknown argument " + a).c_str());
    }
  }
  if (!compare.empty() && !so.profile.empty())
    return usage("plan: --compare takes the plans itself, not --profile as well");
  auto cfg = load_config(so.config);
  if (!or_say(cfg)) return kUsage;
  ps.heading_offset_rad = so.heading_offset_rad.value_or(cfg->stand.heading_offset_rad);
  // each plan on this stand, as a start checks it: the table's limits and
  // what its command signals carry
  auto db = load_databases(cfg->can);
  if (!or_say(db)) return kUsage;
  auto roles = resolve_roles(cfg->can, *db);
  if (!or_say(roles)) return kUsage;
  // the INS's output on this stand: its velocity signals' step and its rate
  const run::InsOutput ins_output = ins_output_of(*roles, cfg->can.ins.velocity_rate_hz);
  auto analysed = [&](const std::string& profile, int& rc) -> std::optional<nlohmann::json> {
    auto p = load_plan(profile, so.overrides);
    if (!or_say(p)) {
      rc = kUsage;
      return std::nullopt;
    }
    run::SequencerSettings q;
    q.profile = p->profile;
    q.start_angle_rad = p->start_angle_rad;
    q.limits = cfg->stand.limits;
    {
      // the command signals of the stand's own table protocol
      const drivers::Devices dev = drivers::make_devices(cfg->can, *roles, {}, 1);
      q.commands = run::command_signals(*dev.ins, *dev.table);
    }
    if (const std::string bad = run::check_plan(q); !bad.empty()) {
      std::fprintf(stderr, "turncalctl: %s: the stand would refuse this plan: %s\n",
                   profile.c_str(), bad.c_str());
      rc = kRefused;
      return std::nullopt;
    }
    auto j = run::plan_json(*p, ps);
    if (!or_say(j)) {
      rc = kRefused;
      return std::nullopt;
    }
    // what the stand's INS output costs this plan
    auto warnings = run::ins_output_costs(*p, ps, ins_output, *j);
    if (!or_say(warnings)) {
      rc = kRefused;
      return std::nullopt;
    }
    (*j)["stand_warnings"] = std::move(*warnings);
    return std::move(*j);
  };
  int rc = kOk;
  nlohmann::json out;
  std::string text;
  if (compare.empty()) {
    auto j = analysed(so.profile.empty() ? cfg->daemon.profile.string() : so.profile, rc);
    if (!j) return rc;
    out = std::move(*j);
    text = run::plan_text(out);
    for (const auto& w : out["stand_warnings"])
      text += "\nwarning: " + w["text"].get<std::string>() + "\n";
  } else {
    ps.sweep = false;  // the plans themselves, side by side
    std::vector<nlohmann::json> each;
    for (const std::string& f : compare) {
      auto j = analysed(f, rc);
      if (!j) return rc;
      for (const auto& w : (*j)["stand_warnings"])
        std::fprintf(stderr, "turncalctl: %s: warning: %s\n", f.c_str(),
                     w["text"].get<std::string>().c_str());
      each.push_back(std::move(*j));
    }
    out = run::compare_json(each);
    text = run::compare_text(out);
  }
  if (!so.json_out.empty() && !write_text(so.json_out, out.dump(2) + "\n")) return kRefused;
  std::printf("%s", as_json ? (out.dump(2) + "\n").c_str() : text.c_str());
  return kOk;
}

int check(int argc, char** argv, int i, bool as_json) {
  SharedOptions so;
  for (; i < argc; ++i) {
    if (std::string bad; shared_option(argc, argv, i, so, bad)) {
      if (!bad.empty()) return usage(("check: " + bad).c_str());
    } else {
      return usage(("check: unknown argument " + std::string(argv[i])).c_str());
    }
  }
  // each step names what it read; the first that fails says why, with the
  // file, line and key
  auto cfg = load_config(so.config);
  if (!or_say(cfg)) return kUsage;
  auto db = load_databases(cfg->can);
  if (!or_say(db)) return kUsage;
  auto roles = resolve_roles(cfg->can, *db);
  if (!or_say(roles)) return kUsage;
  // a CiA 402 drive's PDO layouts, as the daemon checks them at start-up
  if (auto layouts = drivers::check_table(cfg->can, *roles); !or_say(layouts)) return kUsage;
  json out;
  out["config"] = so.config;
  out["dbc"] = json::array();
  for (const auto& f : cfg->can.dbc_files) out["dbc"].push_back(f.string());
  out["messages"] = db->messages.size();
  // what the DBC files hold that was read with a warning or left out (none
  // of it a role's: that would have been an error)
  out["dbc_warnings"] = json::array();
  for (const can::Diagnostic& w : db->warnings) out["dbc_warnings"].push_back(w.describe());
  out["roles"] = json::object();
  for (std::size_t k = 0; k < kRoleCount; ++k) {
    const ResolvedRole& r = roles->roles[k];
    if (r.signal == nullptr) continue;
    out["roles"][std::string(role_key(static_cast<Role>(k)))] =
        r.message->name + "." + r.signal->name +
        (r.signal->unit.empty() ? "" : " [" + r.signal->unit + "]");
  }
  // a DBC without units: read as m/s and us, which the user should know
  for (std::string& w : unitless_role_warnings(*roles)) out["dbc_warnings"].push_back(std::move(w));
  const InsLayout& ins = cfg->can.ins;
  const char* time = ins.time == InsTimeSource::Tag         ? "tag"
                     : ins.time == InsTimeSource::TimeFrame ? "time-frame"
                                                            : "receive";
  const bool one_frame = (*roles)[Role::InsVelEast].message == (*roles)[Role::InsVelNorth].message;
  out["ins"] = {{"time", time},
                {"frames", one_frame ? 1 : 2},
                {"east_sign", ins.east_sign},
                {"north_sign", ins.north_sign},
                {"velocity_rate_hz", ins.velocity_rate_hz}};
  out["table"] = {{"protocol", cfg->can.table.name}};
  // the plans: the one named, else the default and every plan the daemon
  // can be asked for by name
  std::vector<std::string> plans;
  if (!so.profile.empty()) {
    plans.push_back(so.profile);
  } else {
    plans.push_back(cfg->daemon.profile.string());
    std::error_code ec;
    std::vector<std::string> named;
    for (const auto& e : fs::directory_iterator(cfg->daemon.profiles_directory, ec))
      if (e.path().extension() == ".toml" && fs::absolute(e.path()) != fs::absolute(plans[0]))
        named.push_back(e.path().string());
    std::sort(named.begin(), named.end());
    plans.insert(plans.end(), named.begin(), named.end());
  }
  const run::InsOutput ins_output = ins_output_of(*roles, ins.velocity_rate_hz);
  const drivers::Devices dev = drivers::make_devices(cfg->can, *roles, {}, 1);
  bool usable = true;
  out["plans"] = json::array();
  for (const std::string& f : plans) {
    json pj = {{"file", f}};
    auto p = load_plan(f, so.overrides);
    if (!p) {
      pj["error"] = p.error().describe();
      usable = false;
      out["plans"].push_back(pj);
      continue;
    }
    run::SequencerSettings q;
    q.profile = p->profile;
    q.start_angle_rad = p->start_angle_rad;
    q.limits = cfg->stand.limits;
    q.commands = run::command_signals(*dev.ins, *dev.table);
    if (const std::string bad = run::check_plan(q); !bad.empty()) {
      pj["error"] = "the stand would refuse it: " + bad;
      usable = false;
      out["plans"].push_back(pj);
      continue;
    }
    run::PlanningSettings ps;
    ps.sweep = false;
    ps.heading_offset_rad = cfg->stand.heading_offset_rad;
    auto analysed = run::plan_json(*p, ps);
    if (!analysed) {
      pj["error"] = analysed.error().describe();
      usable = false;
      out["plans"].push_back(pj);
      continue;
    }
    auto warnings = run::ins_output_costs(*p, ps, ins_output, *analysed);
    pj["warnings"] = json::array();
    if (warnings)
      for (const auto& w : *warnings) pj["warnings"].push_back(w["text"]);
    out["plans"].push_back(pj);
  }
  out["usable"] = usable;
  if (as_json) {
    std::printf("%s\n", out.dump(2).c_str());
    return usable ? kOk : kRefused;
  }
  std::printf("configuration %s\n", so.config.c_str());
  for (const auto& d : out["dbc"]) std::printf("  DBC %s\n", d.get<std::string>().c_str());
  for (const auto& w : out["dbc_warnings"])
    std::printf("  DBC warning: %s\n", w.get<std::string>().c_str());
  std::printf("  %zu messages; roles:\n", db->messages.size());
  for (const auto& [k, v] : out["roles"].items())
    std::printf("    %-28s %s\n", k.c_str(), v.get<std::string>().c_str());
  const std::string timed =
      ins.time == InsTimeSource::Tag ? "its time tag"
      : ins.time == InsTimeSource::TimeFrame
          ? "the time frame before it (" + out["roles"]["ins_time"].get<std::string>() + ")"
          : "the receive time on a clock of its rate (velocity_rate_hz)";
  std::printf("  INS: velocity in %s, timed by %s; East sign %+g, North sign %+g\n",
              one_frame ? "one frame" : "two frames", timed.c_str(), ins.east_sign, ins.north_sign);
  std::printf("  table: protocol %s\n", cfg->can.table.name.c_str());
  for (const auto& pj : out["plans"]) {
    const std::string f = pj["file"];
    if (pj.contains("error")) {
      std::printf("  plan %s: REFUSED: %s\n", f.c_str(), pj["error"].get<std::string>().c_str());
      continue;
    }
    std::printf("  plan %s: fits the stand\n", f.c_str());
    for (const auto& w : pj["warnings"])
      std::printf("    warning: %s\n", w.get<std::string>().c_str());
  }
  std::printf("%s\n", usable ? "usable" : "NOT usable");
  return usable ? kOk : kRefused;
}

namespace {

/// A number for people: up to 15 significant digits (1e-06, 0.1, 8.38190317153931e-08).
std::string num(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.15g", v);
  return buf;
}

std::string hex(std::uint32_t v) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%X", v);
  return buf;
}

std::string named(const std::string& display, const std::string& written) {
  return display == written ? display : display + " (DBC name " + written + ")";
}

/// "Top = 1", "Sub in 2-3, 5": what selects a multiplexed signal.
std::string selection(const can::Message& m, const can::Signal& s) {
  if (s.selector < 0) return "m" + std::to_string(s.mux_value) + ", no multiplexor";
  std::string out = m.signals[static_cast<std::size_t>(s.selector)].display_name();
  if (s.selected_by.size() == 1 && s.selected_by[0].lo == s.selected_by[0].hi)
    return out + " = " + std::to_string(s.selected_by[0].lo);
  out += " in ";
  for (std::size_t k = 0; k < s.selected_by.size(); ++k) {
    const can::MuxRange& r = s.selected_by[k];
    if (k > 0) out += ", ";
    out += std::to_string(r.lo);
    if (r.hi != r.lo) out += "-" + std::to_string(r.hi);
  }
  return s.selected_by.empty() ? out + "nothing" : out;
}

void print_signal(const can::Message& m, const can::Signal& s) {
  std::string type = s.type == can::ValueType::Float32   ? "float32"
                     : s.type == can::ValueType::Float64 ? "float64"
                     : s.is_signed                       ? "signed"
                                                         : "unsigned";
  std::printf("  %s: start bit %u, %u bits, %s, %s, factor %s, offset %s",
              s.display_name() == s.name ? s.name.c_str() : named(s.display_name(), s.name).c_str(),
              s.start_bit, s.length,
              s.order == can::ByteOrder::LittleEndian ? "little-endian (Intel, @1)"
                                                      : "big-endian (Motorola, @0)",
              type.c_str(), num(s.factor).c_str(), num(s.offset).c_str());
  std::printf(", unit \"%s\", [%s|%s]", s.unit.c_str(), num(s.minimum).c_str(),
              num(s.maximum).c_str());
  if (s.usable) std::printf(", range %s", can::describe_range(s).c_str());
  if (s.is_multiplexor()) std::printf(", multiplexor");
  if (s.mux == can::MuxRole::Multiplexed)
    std::printf(", multiplexed by %s", selection(m, s).c_str());
  if (!s.usable) std::printf(", UNUSABLE: %s", s.problem.c_str());
  std::printf("  (line %u)\n", s.line);
}

void print_warnings(const can::Database& db, std::FILE* to) {
  for (const can::Diagnostic& w : db.warnings) std::fprintf(to, "%s\n", w.describe().c_str());
}

}  // namespace

int dbc(int argc, char** argv, int i, bool as_json) {
  if (i >= argc) return usage("dbc: missing FILE.dbc");
  const std::string path = argv[i++];
  if (i < argc) return usage(("dbc: unknown argument " + std::string(argv[i])).c_str());
  if (as_json) return usage("dbc: prints text only");
  auto db = can::load_dbc(path);
  if (!db) {
    std::fprintf(stderr, "turncalctl: %s\n", db.error().describe().c_str());
    return kRefused;
  }
  std::printf("%s: VERSION \"%s\", %zu messages, nodes:", path.c_str(), db->version.c_str(),
              db->messages.size());
  for (const std::string& n : db->nodes) {
    auto it = db->node_long_names.find(n);
    std::printf(" %s", it == db->node_long_names.end() ? n.c_str() : named(it->second, n).c_str());
  }
  std::printf("\n");
  for (const can::Message& m : db->messages) {
    std::printf("\n%s %s, %s, %u bytes%s, transmitter %s  (line %u)\n", hex(m.id).c_str(),
                m.extended ? "extended" : "standard", named(m.display_name(), m.name).c_str(),
                m.size, m.fd ? " (CAN FD)" : "",
                m.transmitter.empty() ? "none" : m.transmitter.c_str(), m.line);
    for (const can::Signal& s : m.signals) print_signal(m, s);
  }
  if (!db->warnings.empty()) {
    std::printf("\n%zu warnings and notes:\n", db->warnings.size());
    std::fflush(stdout);
    print_warnings(*db, stdout);
  }
  return kOk;
}

int decode(int argc, char** argv, int i, bool as_json) {
  std::vector<std::string> files;
  for (; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--json")
      as_json = true;
    else if (a.size() > 1 && a[0] == '-')
      return usage(("decode: unknown argument " + a).c_str());
    else
      files.push_back(a);
  }
  if (files.size() != 2) return usage("decode: needs FILE.dbc and LOG");
  auto db = can::load_dbc(files[0]);
  if (!or_say(db)) return kUsage;
  for (const can::Diagnostic& w : db->warnings)
    std::fprintf(stderr, "turncalctl: %s\n", w.describe().c_str());
  std::ifstream in_file;
  std::istream* in = &std::cin;
  if (files[1] != "-") {
    in_file.open(files[1], std::ios::binary);
    if (!in_file) {
      std::fprintf(stderr, "turncalctl: cannot open %s\n", files[1].c_str());
      return kUsage;
    }
    in = &in_file;
  }
  const can::FrameCodec codec(*db);
  std::string line;
  can::LogRecord rec;
  std::uint64_t line_no = 0, malformed = 0, first_bad = 0;
  std::string first_why;
  std::vector<double> values;
  while (std::getline(*in, line)) {
    ++line_no;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    if (auto st = can::parse_log_line(line, rec); !st) {
      if (malformed++ == 0) {
        first_bad = line_no;
        first_why = st.error().message;
      }
      continue;
    }
    const can::Frame& f = rec.frame;
    const can::Message* m = codec.message_for(f);
    std::string error;
    if (f.error)
      error = "error frame";
    else if (f.remote)
      error = "remote frame";
    else if (m != nullptr && f.len != m->size)
      error = "length " + std::to_string(f.len) + ", the DBC says " + std::to_string(m->size);
    if (f.error) m = nullptr;
    values.assign(m != nullptr ? m->signals.size() : 0, 0.0);
    const bool carried =
        m != nullptr && error.empty() && codec.decode(f, values) == can::DecodeStatus::Ok;
    // microseconds, as the log has them
    const double t =
        static_cast<double>((rec.time_ns + (rec.time_ns >= 0 ? 500 : -500)) / 1000) / 1e6;
    if (as_json) {
      // keys in the order documented, signals in the DBC's order
      nlohmann::ordered_json j = {
          {"t", t}, {"interface", rec.interface}, {"id", f.id}, {"extended", f.extended}};
      j["message"] = m != nullptr ? nlohmann::ordered_json(m->display_name())
                                  : nlohmann::ordered_json(nullptr);
      nlohmann::ordered_json sig = nlohmann::ordered_json::object();
      if (carried)
        for (std::size_t k = 0; k < values.size(); ++k)
          if (!std::isnan(values[k])) sig[m->signals[k].display_name()] = values[k];
      j["signals"] = std::move(sig);
      if (!error.empty()) j["error"] = error;
      std::printf("%s\n",
                  j.dump(-1, ' ', false, nlohmann::ordered_json::error_handler_t::replace).c_str());
    } else {
      std::printf("(%.6f) %s %s%s %s", t, rec.interface.c_str(), hex(f.id).c_str(),
                  f.extended ? "x" : "", m != nullptr ? m->display_name().c_str() : "?");
      if (carried)
        for (std::size_t k = 0; k < values.size(); ++k) {
          if (std::isnan(values[k])) continue;
          const can::Signal& s = m->signals[k];
          std::printf(" %s=%s%s%s", s.display_name().c_str(), num(values[k]).c_str(),
                      s.unit.empty() ? "" : " ", s.unit.c_str());
          // a value table's name, for an integer signal read as it is (and
          // a value that an int64 holds: no cast beyond its range)
          if (s.factor == 1 && s.offset == 0 && std::abs(values[k]) < 9.2e18)
            if (auto v = s.values.find(static_cast<std::int64_t>(values[k])); v != s.values.end())
              std::printf(" (%s)", v->second.c_str());
        }
      if (!error.empty()) std::printf(" [%s]", error.c_str());
      std::printf("\n");
    }
  }
  // what was decoded went out whole, or the run says it did not
  if (std::fflush(stdout) != 0 || std::ferror(stdout) != 0) {
    std::fprintf(stderr, "turncalctl: decode: cannot write the output: %s\n", std::strerror(errno));
    return kRefused;
  }
  if (malformed > 0)
    std::fprintf(
        stderr, "turncalctl: %s: %llu malformed line%s skipped (the first, line %llu: %s)\n",
        files[1].c_str(), static_cast<unsigned long long>(malformed), malformed == 1 ? "" : "s",
        static_cast<unsigned long long>(first_bad), first_why.c_str());
  return kOk;
}

}  // namespace turncal::ctl
