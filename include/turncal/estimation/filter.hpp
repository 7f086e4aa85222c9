// Kalman filters over the 25-state model (model.md, 8).
//
// SqrtFilter is the estimator: square-root covariance form, P = S S^T, with
// the state scaled internally so that 1e-8 rad/s sits next to 1e3 m. The
// time update is a QR of the stacked factors [Phi S, Q^1/2]; the
// measurement update is the array form, a QR of
//   [[R^1/2, H S], [0, S]]  ->  [[Re^1/2, 0], [Kbar, S+]].
// It never rebuilds P, so it carries the singular P0 of the alignment ties.
//
// JosephFilter is the conventional filter in long double with the Joseph
// form update; tests use it as the cross-check.
#pragma once

#include <Eigen/Core>

#include "turncal/estimation/model.hpp"

namespace turncal::est {

using MeasMat = Eigen::Matrix<double, 2, sx::kN>;
using Meas = Eigen::Vector2d;

/// H: the measurement is the velocity error (model.md, 5).
MeasMat velocity_measurement();

struct UpdateResult {
  Meas innovation;                 ///< z - H x
  Eigen::Matrix2d innovation_cov;  ///< H P H^T + R
  bool ok = true;                  ///< false: the update was numerically degraded and skipped
};

class SqrtFilter {
 public:
  /// Starts at x0 with covariance factor s0 (P0 = s0 s0^T; may be singular
  /// and non-square-triangular). `scale` holds a characteristic size per
  /// state (e.g. prior sigmas); zeros are replaced by 1.
  SqrtFilter(const StateVec& x0, const Eigen::Matrix<double, sx::kN, Eigen::Dynamic>& s0,
             const StateVec& scale);
  void predict(const StateMat& phi, const StateMat& sqrt_q);
  UpdateResult update(const Meas& z, const MeasMat& h, double sigma_z);
  [[nodiscard]] StateVec state() const;
  [[nodiscard]] StateMat covariance() const;
  [[nodiscard]] StateVec sigma() const;

 private:
  StateVec d_;  // scale
  StateVec x_;  // scaled state
  StateMat s_;  // scaled factor, lower triangular after the first step
};

class JosephFilter {
 public:
  using LMat = Eigen::Matrix<long double, sx::kN, sx::kN>;
  using LVec = Eigen::Matrix<long double, sx::kN, 1>;
  JosephFilter(const StateVec& x0, const StateMat& p0);
  void predict(const StateMat& phi, const StateMat& q);
  UpdateResult update(const Meas& z, const MeasMat& h, double sigma_z);
  [[nodiscard]] StateVec state() const { return x_.cast<double>(); }
  [[nodiscard]] StateMat covariance() const { return p_.cast<double>(); }

 private:
  LVec x_;
  LMat p_;
};

}  // namespace turncal::est
