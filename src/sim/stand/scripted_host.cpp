#include "turncal/sim/scripted_host.hpp"

#include <algorithm>
#include <cmath>
#include <random>

#include "turncal/estimation/nominal.hpp"

namespace turncal::stand {
namespace {
constexpr double kDeg = 0.017453292519943295;
}

sim::Config draw_truth(const Plan& plan, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n(0, 1);
  sim::Config c;
  c.latitude_rad = plan.site.latitude_rad;
  c.height_m = plan.site.height_m;
  // drawn in state order, each from its prior
  est::ParamArray drawn{};
  for (std::size_t k = 0; k < drawn.size(); ++k) drawn[k] = plan.priors.params[k] * n(rng);
  c.errors = est::sensor_errors(drawn);
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

ScriptedHost::ScriptedHost(const Plan& plan, const RoleMap& roles, double heading_offset_rad)
    : plan_(plan), roles_(roles), heading_offset_(heading_offset_rad) {}

void ScriptedHost::send(std::vector<StandFrame>& out, double t, bool ins_side, Role any,
                        std::initializer_list<std::pair<Role, double>> values) {
  auto f = roles_.encode_checked(any, values);
  if (!f) {
    // as turncald does: nothing clipped goes out, the run ends with why
    if (!error_) error_ = make_error("scripted host: " + f.error().message);
    done_ = true;
    return;
  }
  out.push_back({t, ins_side, *f});
}

void ScriptedHost::step(double t, const VirtualStand& stand, std::vector<StandFrame>& out) {
  // heartbeat from "the main loop", 10 Hz
  while (static_cast<double>(heartbeat_k_) / 10 <= t) {
    const double th = static_cast<double>(heartbeat_k_) / 10;
    send(out, th, false, Role::HeartbeatCounter,
         {{Role::HeartbeatCounter, static_cast<double>(heartbeat_k_ % 256)},
          {Role::HeartbeatState, done_ ? 0.0 : 1.0}});
    ++heartbeat_k_;
  }
  if (error_) return;
  if (!enabled_ && t >= kEnableAt) {
    send(out, t, false, Role::TableCommand,
         {{Role::TableCommand, 4}, {Role::TableCommandSeq, ++seq_}});
    enabled_ = true;
  }
  if (!aligning_ && t >= kAlignAt) {
    const double heading = heading_offset_ - stand.table().angle(t);
    send(out, t, true, Role::InsCommand,
         {{Role::InsCommand, 1},
          {Role::InsCommandAlignDuration, plan_.profile.align_s},
          {Role::InsCommandHeading, heading / kDeg},
          {Role::InsCommandSeq, ++seq_}});
    aligning_ = true;
  }
  const double t0 = stand.ins().t0();
  if (std::isnan(t0)) return;
  if (next_turn_ < plan_.profile.turns.size() &&
      t >= t0 + plan_.profile.turns[next_turn_].start_s) {
    const TurnSpec& turn = plan_.profile.turns[next_turn_++];
    send(out, t, false, Role::TableCommand,
         {{Role::TableCommand, 2},
          {Role::TableCommandSeq, ++seq_},
          {Role::TableCommandTarget, turn.angle_rad / kDeg},
          {Role::TableCommandRateLimit, turn.max_rate_rps / kDeg}});
  }
  if (t >= t0 + plan_.profile.duration_s) done_ = true;
}

StandLoop::StandLoop(const StandSetup& setup, const can::Database& db, const RoleMap& roles,
                     const Plan* script)
    : stand_(setup, db, roles) {
  if (script != nullptr)
    host_ = std::make_unique<ScriptedHost>(*script, roles, setup.ins.heading_offset_rad);
}

void StandLoop::tick(std::span<const can::Frame> from_bus, std::vector<StandFrame>& out) {
  const double t = next_time();
  const std::size_t first = out.size();
  stand_.advance(t, out);
  for (const can::Frame& f : from_bus) stand_.receive(t, f);
  if (host_ != nullptr) {
    host_->step(t, stand_, from_host_);
    for (const StandFrame& f : from_host_) stand_.receive(f.t_s, f.frame);
    out.insert(out.end(), from_host_.begin(), from_host_.end());
    from_host_.clear();
  }
  std::stable_sort(out.begin() + static_cast<std::ptrdiff_t>(first), out.end(),
                   [](const StandFrame& a, const StandFrame& b) { return a.t_s < b.t_s; });
  ++k_;
}

Status run_offline(const Plan& plan, const CanConfig& can, const can::Database& db,
                   const RoleMap& roles, const StandSetup& setup, can::LogWriter& log,
                   double start_time_s) {
  StandLoop loop(setup, db, roles, &plan);
  std::vector<StandFrame> frames;
  can::LogRecord rec;
  const auto base_ns = static_cast<std::int64_t>(std::llround(start_time_s * 1e9));
  while (!loop.done()) {
    loop.tick({}, frames);
    if (const Error* e = loop.error()) return *e;
    for (const StandFrame& f : frames) {
      rec.time_ns = base_ns + static_cast<std::int64_t>(std::llround(f.t_s * 1e9));
      rec.interface = f.ins_side ? can.ins_interface : can.table_interface;
      rec.frame = f.frame;
      TURNCAL_TRY(log.write(rec));
    }
    frames.clear();
  }
  return Status{Ok{}};
}

}  // namespace turncal::stand
