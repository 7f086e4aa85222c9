// The linear error model of model.md: dynamics F(t) (section 4), hold
// discretization (section 7, matrix exponential and Van Loan), the turn
// transition from encoder samples with the angle-integrated jumps
// (section 7), and the alignment ties x0 = T xi (section 6). Pure.
#pragma once

#include <array>
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

/// What a second pass linearises about (model.md, 8): the nominal's
/// parameters. They turn the computed frame against the true one in
/// azimuth by b3 = -nu0_3 t - Theta_33 (psi - psi_s) to first order (the
/// Earth-rate terms of nu_3, under 1e-7 rad/s, and u2 b1 left out; the
/// nominal's start errors are zero): degrees at the full tactical prior.
/// About the nominal the body-axis errors reach the computed frame
/// through A(psi - b3) rather than A(psi) (the computed body axes are the
/// true ones turned by -b3: C = (I - [b x]) A), and b3 itself couples to
/// the nominal's biases: d(dv)/dt gets -A'(psi - b3) df_z b3 and d(b)/dt
/// gets A'(psi - b3) nu_z b3, A' = dA/dpsi.
struct Nominal {
  std::array<double, sx::kParams> params{};  ///< SI, state order from sx::kNu0
  double psi_start_rad = 0;
  /// The nominal's azimuth error at t with the table at psi, rad.
  [[nodiscard]] double b3(double t_s, double psi_rad) const {
    return -params[static_cast<std::size_t>(2)] * t_s -
           params[static_cast<std::size_t>(sx::theta(3, 3) - sx::kNu0)] * (psi_rad - psi_start_rad);
  }
};

/// F at a still orientation psi (no Omega terms), model.md section 4;
/// with a nominal, linearised about it at time t (see Nominal).
StateMat hold_dynamics(const EarthAt& e, double psi, const Nominal* nominal = nullptr,
                       double t_s = 0);

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
/// With a nominal, F about it at t_mid_s (held over the step).
Discrete discretize_hold(const EarthAt& e, double psi, double dt, const ProcessNoise& noise,
                         const Nominal* nominal = nullptr, double t_mid_s = 0);

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
/// With a nominal, each step about it (its angles turned by -b3, the
/// Theta_.3 and proof-mass jumps included; their own b3 derivatives, of
/// the nominal's Theta_13, Theta_23 and r, are left out).
Discrete turn_transition(const EarthAt& e, std::span<const AngleSample> samples,
                         const ProcessNoise& noise, const TurnIntegrals* integrals = nullptr,
                         const Nominal* nominal = nullptr);

/// Jc = int Omega^2 cos psi dt and Js = int Omega^2 sin psi dt from
/// samples, as int Omega cos psi dpsi and int Omega sin psi dpsi.
TurnIntegrals turn_integrals(std::span<const AngleSample> samples);
/// The closed form for a turn at a constant plateau rate (model.md, 7).
TurnIntegrals turn_integrals_constant_rate(double psi1, double psi2, double plateau_rate);

/// x0 = T xi (model.md, 6) at start orientation psi_s.
XiMat initial_map(const EarthAt& e, double psi_s);

}  // namespace turncal::est
