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
  /// Precondition (model.md, 7): the parameters are constant, so the
  /// parameter rows of phi are those of the identity and those of sqrt_q
  /// are zero. Only the navigation rows are read.
  void predict(const StateMat& phi, const StateMat& sqrt_q);
  UpdateResult update(const Meas& z, const MeasMat& h, double sigma_z);
  [[nodiscard]] StateVec state() const;
  [[nodiscard]] StateMat covariance() const;
  [[nodiscard]] StateVec sigma() const;

 private:
  // Internally the parameters come first: with the factor S lower
  // triangular in that order, S = [[S_pp, 0], [S_np, S_nn]], and a time
  // step leaves S_pp alone, so it costs a 7x18 product and a 7-row
  // re-triangularization instead of a 25x50 QR. The measurement update
  // sweeps the columns from the last with Givens rotations, which keeps S
  // lower triangular (Carlson's idea in array form).
  static constexpr int kP = sx::kParams, kV = sx::kNav;
  using IntVec = StateVec;  // internal order and scale
  using IntMat = StateMat;
  IntVec d_;  // scale, internal order
  IntVec x_;  // scaled state, internal order
  IntMat s_;  // scaled factor, internal order, lower triangular
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
