#include "turncal/plan.hpp"

#include <fstream>
#include <span>
#include <sstream>

#include "toml_reader.hpp"
#include "turncal/earth.hpp"
#include "turncal/estimation/params.hpp"

namespace turncal {
namespace {

using config_detail::pos_of;
using config_detail::Reader;

constexpr double kDeg = earth::kDeg;
constexpr double kArcmin = kDeg / 60;
constexpr double kDegPerRootHour = kDeg / 60;  // deg/sqrt(h) in rad/sqrt(s)
constexpr double kMicroG = 1e-6 * kStandardGravity;

/// The [section] table of root, or an empty one; an error if it is not a table.
Result<const toml::table*> section(const toml::table& root, std::string_view key,
                                   const std::string& file) {
  static const toml::table empty;
  const toml::node* n = root.get(key);
  if (n == nullptr) return &empty;
  if (!n->is_table())
    return make_error("key '" + std::string(key) + "': expected a table",
                      pos_of(n->source(), file));
  return n->as_table();
}

Status read_turns(const toml::node* node, const std::string& file, Plan& plan) {
  if (node == nullptr) return Status{Ok{}};
  const toml::array* turns = node->as_array();
  if (turns == nullptr || !turns->is_array_of_tables())
    return make_error("key 'profile.turn': expected [[profile.turn]] tables",
                      pos_of(node->source(), file));
  for (std::size_t i = 0; i < turns->size(); ++i) {
    const toml::table& t = *(*turns)[i].as_table();
    const std::string prefix = "profile.turn[" + std::to_string(i + 1) + "].";
    Reader r(t, file, prefix);
    TURNCAL_TRY(r.no_unknown_keys({"start_s", "angle_deg", "max_rate_dps", "max_accel_dps2"}));
    for (const char* key : {"start_s", "angle_deg"})
      if (t.get(key) == nullptr)
        return make_error("missing key '" + prefix + key + "'", pos_of(t.source(), file));
    TurnSpec s;
    double angle = 0, rate = 30, accel = 30;
    TURNCAL_TRY(r.number("start_s", s.start_s, 0, 1e6));
    TURNCAL_TRY(r.number("angle_deg", angle, -3600, 3600));
    TURNCAL_TRY(r.number("max_rate_dps", rate, 1e-3, 1000));
    TURNCAL_TRY(r.number("max_accel_dps2", accel, 1e-3, 1000));
    if (angle == 0) return r.error_at(*t.get("angle_deg"), "angle_deg", "a turn must turn");
    s.angle_rad = angle * kDeg;
    s.max_rate_rps = rate * kDeg;
    s.max_accel_rps2 = accel * kDeg;
    plan.profile.turns.push_back(s);
  }
  // In time order, not overlapping, and over before the run ends.
  const TableTrajectory traj(plan.profile);
  for (std::size_t i = 0; i < traj.turns(); ++i) {
    const toml::node& start = *(*turns)[i].as_table()->get("start_s");
    const double next = i + 1 < traj.turns() ? traj.turn_start(i + 1) : plan.profile.duration_s;
    if (!(traj.turn_end(i) < next))
      return make_error("key 'profile.turn[" + std::to_string(i + 1) +
                            "].start_s': the turn ends at " + std::to_string(traj.turn_end(i)) +
                            " s, after " +
                            (i + 1 < traj.turns() ? "the next turn starts" : "the run ends"),
                        pos_of(start.source(), file));
  }
  return Status{Ok{}};
}

/// Sets "a.b.c=VALUE" in root: the tables on the way are made if missing.
Status apply_override(toml::table& root, const std::string& o) {
  const std::string where = "--set " + o;
  const auto eq = o.find('=');
  if (eq == std::string::npos || eq == 0)
    return make_error("expected section.key=VALUE", SourcePos{where, 0, 0});
  const std::string path = o.substr(0, eq);
  toml::table parsed;
  try {
    parsed = toml::parse("v = " + o.substr(eq + 1), where);
  } catch (const toml::parse_error& e) {
    return make_error(std::string(e.description()), SourcePos{where, 0, 0});
  }
  toml::table* t = &root;
  std::size_t from = 0;
  for (;;) {
    const auto dot = path.find('.', from);
    const std::string key = path.substr(from, dot == std::string::npos ? dot : dot - from);
    if (key.empty()) return make_error("empty key in '" + path + "'", SourcePos{where, 0, 0});
    if (dot == std::string::npos) {
      t->insert_or_assign(key, std::move(*parsed.get("v")));
      return Status{Ok{}};
    }
    toml::node* n = t->get(key);
    if (n == nullptr) n = &t->insert_or_assign(key, toml::table{}).first->second;
    if (!n->is_table()) return make_error("'" + key + "' is not a table", SourcePos{where, 0, 0});
    t = n->as_table();
    from = dot + 1;
  }
}

}  // namespace

Result<Plan> parse_plan(std::string_view text, const std::string& file,
                        std::span<const std::string> overrides) {
  toml::table root;
  try {
    root = toml::parse(text, file);
  } catch (const toml::parse_error& e) {
    return make_error(std::string(e.description()), pos_of(e.source(), file));
  }
  for (const std::string& o : overrides) TURNCAL_TRY(apply_override(root, o));
  Plan plan;
  plan.source = file;
  plan.text = std::string(text);
  plan.overrides.assign(overrides.begin(), overrides.end());
  TURNCAL_TRY(
      Reader(root, file, "").no_unknown_keys({"profile", "site", "priors", "noise", "estimation"}));

  TURNCAL_ASSIGN(prof, section(root, "profile", file));
  {
    Reader r(*prof, file, "profile.");
    TURNCAL_TRY(r.no_unknown_keys(
        {"name", "description", "duration_s", "align_s", "start_angle_deg", "turn"}));
    TURNCAL_TRY(r.string("name", plan.name));
    TURNCAL_TRY(r.string("description", plan.description));
    TURNCAL_TRY(r.number("duration_s", plan.profile.duration_s, 1, 1e6));
    TURNCAL_TRY(r.number("align_s", plan.profile.align_s, 0, 1e5));
    double start = 0;
    TURNCAL_TRY(r.number("start_angle_deg", start, -360, 360));
    plan.start_angle_rad = start * kDeg;
    TURNCAL_TRY(read_turns(prof->get("turn"), file, plan));
  }
  TURNCAL_ASSIGN(site, section(root, "site", file));
  {
    Reader r(*site, file, "site.");
    TURNCAL_TRY(r.no_unknown_keys({"latitude_deg", "height_m"}));
    double lat = 0;
    TURNCAL_TRY(r.number("latitude_deg", lat, -89, 89));
    plan.site.latitude_rad = lat * kDeg;
    TURNCAL_TRY(r.number("height_m", plan.site.height_m, -500, 10000));
  }
  TURNCAL_ASSIGN(pri, section(root, "priors", file));
  {
    Reader r(*pri, file, "priors.");
    std::vector<std::string_view> keys = {"v0_mps", "heading_arcmin", "position_m"};
    for (const est::BlockInfo& b : est::kBlocks) keys.push_back(b.prior_key);
    TURNCAL_TRY(r.no_unknown_keys(keys));
    // each block's prior (the parameter table): its default, the plan's
    // value in the key's unit, then SI
    for (const est::BlockInfo& b : est::kBlocks) {
      const std::span<double> span(plan.priors.params.data() + est::block_offset(b.block),
                                   static_cast<std::size_t>(b.size));
      for (double& v : span) v = b.prior_default;
      TURNCAL_TRY(r.numbers(b.prior_key, span, 0, b.prior_max));
      if (b.prior_si_per_key != 1)
        for (double& v : span) v *= b.prior_si_per_key;
    }
    plan.priors.v0_mps = 1e-3;
    plan.priors.position_m = 10;
    double heading = 10;
    TURNCAL_TRY(r.number("v0_mps", plan.priors.v0_mps, 0, 100));
    TURNCAL_TRY(r.number("position_m", plan.priors.position_m, 0, 1e5));
    TURNCAL_TRY(r.number("heading_arcmin", heading, 0, 600));
    plan.priors.heading_rad = heading * kArcmin;
    plan.priors.align_s = plan.profile.align_s;
  }
  TURNCAL_ASSIGN(noise, section(root, "noise", file));
  {
    Reader r(*noise, file, "noise.");
    TURNCAL_TRY(r.no_unknown_keys({"arw_dprh", "vrw_ug_rthz", "velocity_mps"}));
    double arw = 0.05, vrw = 50;
    plan.sigma_z = 1e-3;
    TURNCAL_TRY(r.number("arw_dprh", arw, 0, 100));
    TURNCAL_TRY(r.number("vrw_ug_rthz", vrw, 0, 1e5));
    TURNCAL_TRY(r.number("velocity_mps", plan.sigma_z, 1e-9, 10));
    plan.arw = arw * kDegPerRootHour;
    plan.vrw = vrw * kMicroG;
  }
  TURNCAL_ASSIGN(est, section(root, "estimation", file));
  {
    Reader r(*est, file, "estimation.");
    TURNCAL_TRY(r.no_unknown_keys({"epoch_s", "measurement", "sharp_ratio"}));
    TURNCAL_TRY(r.number("epoch_s", plan.epoch_s, 1e-3, 600));
    TURNCAL_TRY(r.number("sharp_ratio", plan.sharp_ratio, 0, 1));
    std::string m = "sample";
    TURNCAL_TRY(r.string("measurement", m));
    if (m != "sample" && m != "mean")
      return r.error_at(*est->get("measurement"), "measurement",
                        "expected \"sample\" (nearest sample) or \"mean\" (mean around the epoch)");
    plan.mean_measurement = m == "mean";
  }
  return plan;
}

Result<Plan> load_plan(const std::string& path, std::span<const std::string> overrides) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return make_error("cannot open profile file", SourcePos{path, 0, 0});
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_plan(ss.str(), path, overrides);
}

}  // namespace turncal
