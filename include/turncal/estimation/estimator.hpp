// Single-loop estimation (model.md, 8): one square-root filter over both
// holds and the turn, driven by the INS output velocity.
#pragma once

#include <array>
#include <vector>

#include "turncal/estimation/filter.hpp"
#include "turncal/estimation/timeline.hpp"

namespace turncal::est {

/// Prior standard deviations of the independent start variables (model.md, 6).
struct Priors {
  double v0_mps = 1e-3;                      ///< initial velocity error, per axis
  double position_m = 10;                    ///< position error, per axis
  double heading_rad = 0;                    ///< heading error given at alignment
  double align_s = 120;                      ///< alignment length (nbar variance q_a / T_align)
  std::array<double, sx::kParams> params{};  ///< the 18 parameters, SI
};

struct VelocityObs {
  double t_s;
  double ve;
  double vn;
};

struct EstimationInput {
  TimelineInput timeline;
  Priors priors;
  double sigma_z = 1e-3;              ///< velocity output noise, m/s
  bool mean_measurement = false;      ///< mean over the epoch instead of the nearest sample
  std::vector<VelocityObs> velocity;  ///< ascending in time
};

struct Innovation {
  double t_s;
  Meas value;
  Eigen::Matrix2d cov;
};

struct EstimationResult {
  StateVec x;
  StateMat p;
  std::vector<double> epoch_t;
  std::vector<StateVec> sigma_history;  ///< sqrt(diag P) after each epoch
  std::vector<Innovation> innovations;
  std::size_t degraded_updates = 0;
};

/// Sigma_xi (diagonal) from the priors and the process noise.
XiVec prior_sigmas(const Priors& priors, const ProcessNoise& noise);

/// Runs the square-root filter over the record.
EstimationResult estimate(const EstimationInput& in);

}  // namespace turncal::est
