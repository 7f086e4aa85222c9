// The linear error model of model.md: dynamics F(t) (section 4), hold
// discretization (section 7, matrix exponential and Van Loan), the turn
// transition from encoder samples with the angle-integrated jumps
// (section 7), and the alignment ties x0 = T xi (section 6). Pure.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

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
  double lat_rad;   ///< the site's latitude
  double height_m;  ///< and height
  static EarthAt at(const Site& site);
};

/// White-noise spectral densities (model.md, 4).
struct ProcessNoise {
  double q_a = 0;  ///< accelerometer, (m/s^2)^2/Hz (VRW squared)
  double q_g = 0;  ///< gyro, (rad/s)^2/Hz (ARW squared)
};

/// The nominal's navigation state at one time (model.md, 8): what the
/// INS computes with the nominal's errors, noise-free, from its start at
/// zero errors.
struct NominalState {
  double t_s = 0;
  double ve = 0, vn = 0;  ///< computed velocity East, North, m/s
  double dlat_rad = 0;    ///< computed latitude minus the site's
  /// The computed attitude against the true one, C A(psi)^T: C the
  /// computed body-to-local-level matrix, A(psi) the true (model.md, 1);
  /// the identity about zero errors.
  Eigen::Matrix3d e = Eigen::Matrix3d::Identity();
};

/// What a second pass linearises about (model.md, 8): the nominal's
/// parameters and its navigation state over the run (its velocity of up
/// to hundreds of m/s, its latitude, its attitude turned by degrees in
/// azimuth at large errors). About it the model is the INS's error
/// equations in the perturbation of that state: the velocity perturbed
/// dv, the position perturbed in latitude and longitude, and the attitude
/// by psi with C' = (I - [psi x]) C, carried in the model's coordinates
/// (a1 = -dlat, a2 = cos(lat) dlon, b = psi - (a1, a2, tan(lat) a2)), so
/// that about zero it is the model of model.md, 4.
struct Nominal {
  std::array<double, sx::kParams> params{};  ///< SI, state order from sx::kNu0
  /// Ascending in time, the first at or before t0; shared by the passes
  /// that use it. Linear between its samples, held beyond its ends; none
  /// (or empty) is the state at zero errors, which for_each_step refuses.
  std::shared_ptr<const std::vector<NominalState>> track;
  /// The state at t_s; `hint` is the search's start, kept between calls.
  [[nodiscard]] NominalState at(double t_s, std::size_t& hint) const;
  [[nodiscard]] NominalState at(double t_s) const {
    std::size_t hint = SIZE_MAX;  // none
    return at(t_s, hint);
  }
};

/// The sample of a series ascending in time at t_s, its time t_s: linear
/// between its samples, held beyond its ends; an empty series is the
/// default sample. `hint` is where the search starts, kept between calls
/// (walks forward in order; searches when t_s is before it or it is past
/// the end); `mix(a, b, f)` is a + f (b - a).
template <class Sample, class Mix>
Sample sample_at(const std::vector<Sample>& s, double t_s, std::size_t& hint, const Mix& mix) {
  Sample o{};
  if (!s.empty()) {
    if (hint >= s.size() || s[hint].t_s > t_s) {
      const auto it = std::upper_bound(s.begin(), s.end(), t_s,
                                       [](double t, const Sample& n) { return t < n.t_s; });
      hint = it == s.begin() ? 0 : static_cast<std::size_t>(it - s.begin()) - 1;
    }
    while (hint + 1 < s.size() && s[hint + 1].t_s <= t_s) ++hint;
    const Sample& a = s[hint];
    o = hint + 1 == s.size() || t_s <= a.t_s
            ? a
            : mix(a, s[hint + 1], (t_s - a.t_s) / (s[hint + 1].t_s - a.t_s));
  }
  o.t_s = t_s;
  return o;
}

/// A(psi), the body-to-geographic rotation at orientation psi (model.md, 1).
Eigen::Matrix3d body_to_geographic(double psi);

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
/// With a nominal, each step about it: the Theta_.3 and proof-mass jumps
/// turned by its attitude (its proof-mass acceleration in the specific
/// force that tilts turn, 0.12 m/s^2 or 1.2% of g at 3 cm and 2 rad/s,
/// left out).
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
