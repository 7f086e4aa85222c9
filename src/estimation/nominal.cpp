#include "turncal/estimation/nominal.hpp"

#include <algorithm>
#include <cmath>

#include "turncal/physics/profile.hpp"
#include "turncal/physics/strapdown.hpp"

namespace turncal::est {

namespace {
/// Each parameter's term in the strapdown's errors, in state order (Theta
/// row-major): f(state index, the term).
template <typename Errors, typename F>
void each_term(Errors& e, F&& f) {
  for (int i = 0; i < 3; ++i) f(sx::kNu0 + i, e.nu0(i));
  for (int i = 1; i <= 3; ++i)
    for (int j = 1; j <= 3; ++j) f(sx::theta(i, j), e.theta(i - 1, j - 1));
  for (int i = 0; i < 2; ++i) {
    f(sx::kDf0 + i, e.df0(i));
    f(sx::kG + i, e.g(i));
    f(sx::kR + i, e.r(i));
  }
}
}  // namespace

sim::SensorErrors sensor_errors(const ParamArray& params) {
  sim::SensorErrors e;
  each_term(e,
            [&](int state, double& v) { v = params[static_cast<std::size_t>(state - sx::kNu0)]; });
  return e;
}

ParamArray params_of(const sim::SensorErrors& e) {
  ParamArray p{};
  each_term(e,
            [&](int state, const double& v) { p[static_cast<std::size_t>(state - sx::kNu0)] = v; });
  return p;
}

Result<NominalRun> strapdown_nominal(const EstimationInput& in,
                                     const std::array<double, sx::kParams>& params) {
  const TimelineInput& tl = in.timeline;
  if (!(tl.duration_s > 0)) return make_error("the nominal needs a run of positive length");
  if (tl.encoder.empty() && !tl.turns.empty())
    return make_error("the nominal needs the encoder samples of the turns");
  // The table angle relative to t0 (the simulation's), from the encoder in
  // each turn window (model sense: psi - psi_s), at rest between them.
  TableMotion motion(0.0);
  const std::span<const AngleSample> enc(tl.encoder);
  for (const TurnWindow& w : tl.turns) {
    std::vector<AngleSample> s{{w.t_start_s, psi_at(enc, w.t_start_s)}};
    auto it = std::upper_bound(enc.begin(), enc.end(), w.t_start_s,
                               [](double v, const AngleSample& a) { return v < a.t_s; });
    for (; it != enc.end() && it->t_s < w.t_end_s; ++it) s.push_back(*it);
    s.push_back({w.t_end_s, psi_at(enc, w.t_end_s)});
    for (std::size_t k = 0; k + 1 < s.size(); ++k) {
      const double dt = s[k + 1].t_s - s[k].t_s;
      if (!(dt > 0)) continue;
      motion.append(s[k].t_s, s[k].psi_rad - tl.psi_start_rad,
                    (s[k + 1].psi_rad - s[k].psi_rad) / dt, 0);
    }
    motion.append(w.t_end_s, s.back().psi_rad - tl.psi_start_rad, 0, 0);
  }
  sim::Config c;
  c.latitude_rad = tl.site.latitude_rad;
  c.height_m = tl.site.height_m;
  c.psi_start_rad = tl.psi_start_rad;
  c.profile.duration_s = tl.duration_s;
  c.profile.align_s = in.priors.align_s;
  c.motion = &motion;
  c.motion_t0_s = 0;
  if (!(in.second_pass.nominal_imu_rate_hz >= c.output_rate_hz))
    return make_error("the nominal's IMU rate must be at least its output rate");
  c.imu_rate_hz = in.second_pass.nominal_imu_rate_hz;
  c.encoder_rate_hz = 0;  // the motion is the encoder's already
  c.nav_rate_hz = kNominalTrackRateHz;
  c.errors = sensor_errors(params);
  const sim::Run run = sim::simulate(c);
  NominalRun out;
  out.velocity.reserve(run.velocity.size());
  for (const sim::VelocitySample& v : run.velocity) out.velocity.push_back({v.t_s, v.ve, v.vn});
  out.track.reserve(run.nav.size());
  for (const sim::NavSample& n : run.nav) {
    // E = C A(psi)^T, A(psi) the true body-to-geographic rotation
    out.track.push_back({n.t_s, n.ve, n.vn, n.lat_rad - tl.site.latitude_rad,
                         n.c_bn * body_to_geographic(n.psi_rad).transpose()});
  }
  return out;
}

}  // namespace turncal::est
