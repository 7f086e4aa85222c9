#include "turncal/estimation/estimator.hpp"

#include <algorithm>
#include <cmath>

namespace turncal::est {
namespace {

/// The measurement for the epoch ending at t: the nearest sample (within
/// half an epoch) or the mean of the samples in (t - epoch, t].
bool measurement_at(const EstimationInput& in, double t, Meas& z, double& sigma) {
  const auto& v = in.velocity;
  const double epoch = in.timeline.epoch_s;
  if (in.mean_measurement) {
    auto lo = std::upper_bound(v.begin(), v.end(), t - epoch,
                               [](double x, const VelocityObs& o) { return x < o.t_s; });
    auto hi = std::upper_bound(v.begin(), v.end(), t + 1e-9,
                               [](double x, const VelocityObs& o) { return x < o.t_s; });
    if (lo == hi) return false;
    z.setZero();
    for (auto it = lo; it != hi; ++it) z += Meas(it->ve, it->vn);
    const auto n = static_cast<double>(hi - lo);
    z /= n;
    sigma = in.sigma_z / std::sqrt(n);
    return true;
  }
  auto it = std::lower_bound(v.begin(), v.end(), t,
                             [](const VelocityObs& o, double x) { return o.t_s < x; });
  const VelocityObs* best = nullptr;
  if (it != v.end()) best = &*it;
  if (it != v.begin() && (best == nullptr || t - (it - 1)->t_s < best->t_s - t)) best = &*(it - 1);
  if (best == nullptr || std::fabs(best->t_s - t) > 0.5 * epoch) return false;
  z = Meas(best->ve, best->vn);
  sigma = in.sigma_z;
  return true;
}

}  // namespace

XiVec prior_sigmas(const Priors& pr, const ProcessNoise& noise) {
  XiVec s = XiVec::Zero();
  s(sxi::kV0) = s(sxi::kV0 + 1) = pr.v0_mps;
  s(sxi::kDrE) = s(sxi::kDrN) = pr.position_m;
  s(sxi::kDpsi0) = pr.heading_rad;
  s(sxi::kNbar) = s(sxi::kNbar + 1) = pr.align_s > 0 ? std::sqrt(noise.q_a / pr.align_s) : 0.0;
  for (int p = 0; p < sx::kParams; ++p)
    s(sxi::kParams + p) = pr.params[static_cast<std::size_t>(p)];
  return s;
}

EstimationResult estimate(const EstimationInput& in) {
  const EarthAt e = EarthAt::at(in.timeline.site);
  const XiMat t = initial_map(e, in.timeline.psi_start_rad);
  const XiVec sxi_diag = prior_sigmas(in.priors, in.timeline.noise);
  const Eigen::Matrix<double, sx::kN, Eigen::Dynamic> s0 = t * sxi_diag.asDiagonal();
  // internal scaling: the prior sigma of each state, floored where the
  // prior leaves a state exactly known
  StateVec scale = s0.rowwise().norm();
  SqrtFilter f(StateVec::Zero(), s0, scale);
  const MeasMat h = velocity_measurement();
  EstimationResult r;
  for_each_step(in.timeline, [&](const TimelineStep& step) {
    f.predict(step.d->phi, step.d->sqrt_q);
    Meas z;
    double sigma = in.sigma_z;
    if (measurement_at(in, step.t_to, z, sigma)) {
      const UpdateResult u = f.update(z, h, sigma);
      if (!u.ok) ++r.degraded_updates;
      r.innovations.push_back({step.t_to, u.innovation, u.innovation_cov});
    }
    r.epoch_t.push_back(step.t_to);
    r.sigma_history.push_back(f.sigma());
  });
  r.x = f.state();
  r.p = f.covariance();
  return r;
}

}  // namespace turncal::est
