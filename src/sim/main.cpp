// turncal-sim: the virtual stand. This first version has the offline mode:
// a whole run of a plan, the table commanded as a host would, written
// straight to a candump log with the frames and times a capture would
// have, and the injected truth written as JSON (SI, model.md's names).
//
//   turncal-sim --offline --out RUN.log --truth TRUTH.json
//               [--profile PLAN.toml] [--config turncal.toml] [--seed N]
//               [--heading-offset DEG] [--start-time UNIX_S]
#include <nlohmann/json.hpp>

#include <cstdio>
#include <cstring>
#include <fstream>
#include <random>
#include <string>

#include "turncal/can/candump.hpp"
#include "turncal/config.hpp"
#include "turncal/drivers/scripted_host.hpp"
#include "turncal/drivers/virtual_stand.hpp"
#include "turncal/earth.hpp"
#include "turncal/estimation/state.hpp"
#include "turncal/plan.hpp"

using namespace turncal;

namespace {

constexpr double kDeg = 0.017453292519943295;

struct Options {
  bool offline = false;
  std::string out, truth;
  std::string profile = std::string(TURNCAL_DATA_DIR) + "/profiles/tactical.toml";
  std::string config = std::string(TURNCAL_DATA_DIR) + "/turncal.toml";
  std::uint64_t seed = 1;
  double heading_offset_deg = 0;
  double start_time_s = 1767225600;  // 2026-01-01T00:00:00Z: runs are reproducible
};

int usage(const char* why) {
  if (why != nullptr) std::fprintf(stderr, "turncal-sim: %s\n", why);
  std::fprintf(stderr,
               "usage: turncal-sim --offline --out RUN.log --truth TRUTH.json\n"
               "                   [--profile PLAN.toml] [--config turncal.toml] [--seed N]\n"
               "                   [--heading-offset DEG] [--start-time UNIX_S]\n");
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
    } else if (a == "--out" || a == "--truth" || a == "--profile" || a == "--config") {
      const char* v = value();
      if (v == nullptr) return false;
      (a == "--out"       ? o.out
       : a == "--truth"   ? o.truth
       : a == "--profile" ? o.profile
                          : o.config) = v;
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

/// Errors drawn from the plan's priors.
sim::Config draw_truth(const Plan& plan, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n(0, 1);
  sim::Config c;
  c.latitude_rad = plan.site.latitude_rad;
  c.height_m = plan.site.height_m;
  const auto& p = plan.priors.params;
  for (int i = 0; i < 3; ++i) c.errors.nu0(i) = p[static_cast<std::size_t>(i)] * n(rng);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      c.errors.theta(i, j) = p[static_cast<std::size_t>(3 + 3 * i + j)] * n(rng);
  for (int i = 0; i < 2; ++i) c.errors.df0(i) = p[static_cast<std::size_t>(12 + i)] * n(rng);
  for (int i = 0; i < 2; ++i) c.errors.g(i) = p[static_cast<std::size_t>(14 + i)] * n(rng);
  for (int i = 0; i < 2; ++i) c.errors.r(i) = p[static_cast<std::size_t>(16 + i)] * n(rng);
  c.start.v0 = Eigen::Vector2d(plan.priors.v0_mps * n(rng), plan.priors.v0_mps * n(rng));
  c.start.dr_e_m = plan.priors.position_m * n(rng);
  c.start.dr_n_m = plan.priors.position_m * n(rng);
  c.start.dpsi0_rad = plan.priors.heading_rad * n(rng);
  c.noise.arw = plan.arw;
  c.noise.vrw = plan.vrw;
  c.noise.velocity_sigma = plan.sigma_z;
  c.seed = rng();
  return c;
}

nlohmann::json truth_json(const sim::Config& c, const Plan& plan, const Options& o) {
  using nlohmann::json;
  json e = json::object();
  std::size_t k = 0;
  auto put = [&](double v) { e[std::string(est::kParamNames[k++])] = v; };
  for (int i = 0; i < 3; ++i) put(c.errors.nu0(i));
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) put(c.errors.theta(i, j));
  for (int i = 0; i < 2; ++i) put(c.errors.df0(i));
  for (int i = 0; i < 2; ++i) put(c.errors.g(i));
  for (int i = 0; i < 2; ++i) put(c.errors.r(i));
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

int offline(const Options& o) {
  auto plan = load_plan(o.profile);
  if (!plan) return std::fprintf(stderr, "%s\n", plan.error().describe().c_str()), 1;
  auto cfg = load_config(o.config);
  if (!cfg) return std::fprintf(stderr, "%s\n", cfg.error().describe().c_str()), 1;
  auto db = load_databases(cfg->can);
  if (!db) return std::fprintf(stderr, "%s\n", db.error().describe().c_str()), 1;
  auto roles = resolve_roles(cfg->can, *db);
  if (!roles) return std::fprintf(stderr, "%s\n", roles.error().describe().c_str()), 1;

  stand::StandSetup setup;
  setup.ins.sim = draw_truth(*plan, o.seed);
  setup.ins.heading_offset_rad = o.heading_offset_deg * kDeg;
  setup.table_angle0_rad = plan->start_angle_rad;
  if (!plan->profile.turns.empty()) {
    setup.table_limits.max_accel_rps2 = plan->profile.turns[0].max_accel_rps2;
    for (const TurnSpec& t : plan->profile.turns)
      setup.table_limits.max_rate_rps = std::max(setup.table_limits.max_rate_rps, t.max_rate_rps);
  }
  setup.seed = o.seed;
  {
    std::ofstream tj(o.truth);
    tj << truth_json(setup.ins.sim, *plan, o).dump(2) << "\n";
    if (!tj) return std::fprintf(stderr, "%s: cannot write the truth file\n", o.truth.c_str()), 1;
  }
  auto log = can::LogWriter::open(o.out);
  if (!log) return std::fprintf(stderr, "%s\n", log.error().describe().c_str()), 1;

  const auto run = stand::run_offline(*plan, cfg->can, *db, *roles, setup, *log, o.start_time_s);
  if (!run) return std::fprintf(stderr, "%s\n", run.error().describe().c_str()), 1;
  if (auto c = log->close(); !c)
    return std::fprintf(stderr, "%s\n", c.error().describe().c_str()), 1;
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  std::string err;
  if (!parse(argc, argv, o, err)) return usage(err.empty() ? nullptr : err.c_str());
  if (!o.offline) return usage("only --offline is built so far");
  if (o.out.empty() || o.truth.empty()) return usage("--offline needs --out and --truth");
  return offline(o);
}
