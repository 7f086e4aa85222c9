// The linear error model of model.md: dynamics F(t) (section 4), hold
// discretization (section 7, matrix exponential and Van Loan), the turn
// transition from encoder samples with the angle-integrated jumps
// (section 7), and the alignment ties x0 = T xi (section 6). Pure.
#pragma once

#include <cmath>
#include <span>

#include "turncal/estimation/state.hpp"

namespace turncal::est {

struct Site {
  double latitude_rad = 0;
  double height_m = 0;
};

/// Earth quantities at the site, as the model uses them.
struct EarthAt {
  double g;   ///< normal gravity, m/s^2
  double u2;  ///< u cos(lat), rad/s
  double u3;  ///< u sin(lat), rad/s
  double rm;  ///< R_M + h, m
  double rn;  ///< R_N + h, m
  double tan_lat;
  static EarthAt at(const Site& site);
};

/// White-noise spectral densities (model.md, 4).
struct ProcessNoise {
  double q_a = 0;  ///< accelerometer, (m/s^2)^2/Hz (VRW squared)
  double q_g = 0;  ///< gyro, (rad/s)^2/Hz (ARW squared)
};

/// F at a still orientation psi (no Omega terms), model.md section 4.
StateMat hold_dynamics(const EarthAt& e, double psi);

/// Transition and process noise over one step of length dt at rest.
struct Discrete {
  StateMat phi;
  StateMat q;
  StateMat sqrt_q;  ///< a square root of q (sqrt_q sqrt_q^T = q), for the square-root filter
};

/// A square root of a symmetric positive semi-definite matrix, negative
/// eigenvalues from round-off clamped to zero.
StateMat psd_sqrt(const StateMat& q);
/// expm(F dt) and Van Loan's Q_d; only the 7 navigation rows are non-trivial.
Discrete discretize_hold(const EarthAt& e, double psi, double dt, const ProcessNoise& noise);

/// One encoder sample, in the model's sense: psi counter-clockwise from
/// East (model.md, 1), unwrapped, and the experiment time.
struct AngleSample {
  double t_s;
  double psi_rad;
};

/// Transition (and process noise) over a turn sampled by the encoder, from
/// the first sample's time to the last's: bounded terms propagated in
/// sub-steps at the sample times, the Theta_.3 tilt jump integrated over
/// angle, and the proof-mass velocity jump from Jc, Js (model.md, 7). The
/// table is still at the first and the last sample. The proof-mass jump
/// is applied step by step where the angle changes. `integrals`, when
/// given, replaces Jc, Js from the samples (the constant-rate fallback):
/// with its plateau rate the jump is spread over the samples as the closed
/// form has it, without one it is applied at the end.
struct TurnIntegrals {
  double jc;
  double js;
  double plateau_rate = NAN;  ///< rad/s, signed; NaN: only the totals are known
};
Discrete turn_transition(const EarthAt& e, std::span<const AngleSample> samples,
                         const ProcessNoise& noise, const TurnIntegrals* integrals = nullptr);

/// Jc = int Omega^2 cos psi dt and Js = int Omega^2 sin psi dt from
/// samples, as int Omega cos psi dpsi and int Omega sin psi dpsi.
TurnIntegrals turn_integrals(std::span<const AngleSample> samples);
/// The closed form for a turn at a constant plateau rate (model.md, 7).
TurnIntegrals turn_integrals_constant_rate(double psi1, double psi2, double plateau_rate);

/// x0 = T xi (model.md, 6) at start orientation psi_s.
XiMat initial_map(const EarthAt& e, double psi_s);

}  // namespace turncal::est
