// The reference scenarios of the estimation core, read from their profile
// files in config/profiles/ (latitude 55.75 deg, height 200 m, 3600 s, +180
// deg turn at 1800 s, 30 deg/s, 30 deg/s^2,
// heading error 10 arcmin, position error 10 m, epoch 1 s).
#pragma once

#include <random>
#include <stdexcept>
#include <string>

#include "turncal/build_paths.hpp"
#include "turncal/earth.hpp"
#include "turncal/estimation/estimator.hpp"
#include "turncal/physics/strapdown.hpp"
#include "turncal/plan.hpp"

namespace scenario {

using namespace turncal;
inline constexpr double kDeg = earth::kDeg;
inline constexpr double kDegPerHour = kDeg / 3600.0;
inline constexpr double kG0 = 9.80665;

struct Scenario {
  est::Priors priors;
  double arw;      ///< rad/sqrt(s)
  double vrw;      ///< m/s/sqrt(s)
  double sigma_z;  ///< m/s
  Profile profile;
  est::Site site;
};

/// A reference scenario from its profile file in config/profiles/.
inline Scenario from_plan(const std::string& name) {
  const auto plan = load_plan(std::string(turncal::build::source_dir) + "/config/profiles/" + name);
  if (!plan) throw std::runtime_error(plan.error().describe());
  return Scenario{plan->priors, plan->arw, plan->vrw, plan->sigma_z, plan->profile, plan->site};
}

inline Scenario tactical() {
  return from_plan("tactical.toml");
}

inline Scenario navigation_grade() {
  return from_plan("navigation-grade.toml");
}

/// The classic profile of both reference scenarios.
inline Profile reference_profile() {
  return tactical().profile;
}

inline est::TimelineInput timeline(const Scenario& s, double psi_s, const TableTrajectory& table,
                                   const std::vector<sim::EncoderSample>& enc) {
  est::TimelineInput in;
  in.site = s.site;
  in.noise = {s.vrw * s.vrw, s.arw * s.arw};
  in.epoch_s = 1.0;
  in.duration_s = table.duration();
  in.psi_start_rad = psi_s;
  for (std::size_t i = 0; i < table.turns(); ++i) {
    const double t1 = table.turn_start(i), t2 = table.turn_end(i);
    in.turns.push_back({t1, t2, table.at(t2).angle - table.at(t1).angle, table.peak_rate(i)});
  }
  for (const auto& e : enc) in.encoder.push_back({e.t_s, psi_s + e.angle_rad});
  return in;
}

/// Encoder samples of the profile at 200 Hz (truth, no simulation needed).
inline std::vector<sim::EncoderSample> encoder_of(const TableTrajectory& table, double duration_s) {
  std::vector<sim::EncoderSample> out;
  for (long k = 0; k <= static_cast<long>(duration_s * 200); ++k) {
    const double t = static_cast<double>(k) / 200.0;
    out.push_back({t, table.at(t).angle});
  }
  return out;
}

/// Draws the injected errors from the prior; returns them as xi.
inline est::XiVec draw(const Scenario& s, std::mt19937_64& rng) {
  std::normal_distribution<double> n(0, 1);
  const est::XiVec sig = est::prior_sigmas(s.priors, {s.vrw * s.vrw, s.arw * s.arw});
  est::XiVec xi = est::XiVec::Zero();
  for (int i = 0; i < est::sxi::kN; ++i)
    if (i != est::sxi::kNbar && i != est::sxi::kNbar + 1)
      xi(i) = sig(i) * n(rng);  // the sim makes its own
  return xi;
}

/// The simulation of the scenario's site and profile (by default the
/// reference ones) with the errors of `xi` injected, noise off.
inline sim::Config sim_config(const est::XiVec& xi, double psi_s,
                              const Scenario& where = tactical()) {
  using namespace est;
  sim::Config c;
  c.latitude_rad = where.site.latitude_rad;
  c.longitude_rad = 37.6 * kDeg;
  c.height_m = where.site.height_m;
  c.psi_start_rad = psi_s;
  c.profile = where.profile;
  c.start.v0 = xi.segment<2>(sxi::kV0);
  c.start.dr_e_m = xi(sxi::kDrE);
  c.start.dr_n_m = xi(sxi::kDrN);
  c.start.dpsi0_rad = xi(sxi::kDpsi0);
  const auto p = xi.segment<sx::kParams>(sxi::kParams);
  c.errors.nu0 = p.segment<3>(0);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) c.errors.theta(i, j) = p(3 + 3 * i + j);
  c.errors.df0 = p.segment<2>(12);
  c.errors.g = p.segment<2>(14);
  c.errors.r = p.segment<2>(16);
  return c;
}

/// The same with the scenario's noise and alignment length.
inline sim::Config sim_config(const Scenario& s, const est::XiVec& xi, double psi_s,
                              std::uint64_t seed) {
  sim::Config c = sim_config(xi, psi_s, s);
  c.profile.align_s = s.priors.align_s;
  c.noise.arw = s.arw;
  c.noise.vrw = s.vrw;
  c.noise.velocity_sigma = s.sigma_z;
  c.seed = seed;
  return c;
}

}  // namespace scenario
