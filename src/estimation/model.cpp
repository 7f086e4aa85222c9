#include "turncal/estimation/model.hpp"

#include <Eigen/Eigenvalues>
#include <cmath>
#include <unsupported/Eigen/MatrixFunctions>

#include "turncal/earth.hpp"

namespace turncal::est {
namespace {

using Mat3 = Eigen::Matrix3d;

/// A(psi), body to geographic (model.md, 1).
Mat3 rot(double psi) {
  const double c = std::cos(psi), s = std::sin(psi);
  Mat3 a;
  a << c, -s, 0, s, c, 0, 0, 0, 1;
  return a;
}

/// G Q G^T: accelerometer noise in the dv rows, gyro noise in the b rows
/// (isotropic, so the rotation A(psi) leaves it unchanged).
StateMat noise_input(const ProcessNoise& n) {
  StateMat q = StateMat::Zero();
  q(sx::kDv, sx::kDv) = q(sx::kDv + 1, sx::kDv + 1) = n.q_a;
  for (int i = 0; i < 3; ++i) q(sx::kB + i, sx::kB + i) = n.q_g;
  return q;
}

}  // namespace

StateMat psd_sqrt(const StateMat& q) {
  // Scaled by its diagonal first: Q spans some 20 orders of magnitude (the
  // a rows see q_a dt^3 / R^2), and an unscaled eigensolver would bury the
  // small blocks in the round-off of the large ones.
  StateVec d = q.diagonal().cwiseMax(0.0).cwiseSqrt();
  for (int i = 0; i < sx::kN; ++i)
    if (!(d(i) > 0)) d(i) = 1;
  const StateMat qs =
      d.cwiseInverse().asDiagonal() * (0.5 * (q + q.transpose())) * d.cwiseInverse().asDiagonal();
  Eigen::SelfAdjointEigenSolver<StateMat> es(qs);
  const StateVec ev = es.eigenvalues().cwiseMax(0.0).cwiseSqrt();
  return d.asDiagonal() * es.eigenvectors() * ev.asDiagonal();
}

EarthAt EarthAt::at(const Site& site) {
  const double lat = site.latitude_rad;
  return EarthAt{earth::normal_gravity(lat, site.height_m),
                 earth::kRate * std::cos(lat),
                 earth::kRate * std::sin(lat),
                 earth::meridian_radius(lat) + site.height_m,
                 earth::normal_radius(lat) + site.height_m,
                 std::tan(lat)};
}

StateMat hold_dynamics(const EarthAt& e, double psi, const Nominal* nominal, double t_s) {
  using namespace sx;
  StateMat f = StateMat::Zero();
  // the computed frame's view of body axes: A(psi - b3) about a nominal
  const double psi_c = nominal != nullptr ? psi - nominal->b3(t_s, psi) : psi;
  const Mat3 a = rot(psi_c);
  // d(dv1)/dt =  2 u3 dv2 - g (b2 + a2) + da1
  // d(dv2)/dt = -2 u3 dv1 + g (b1 + a1) + da2,   da = A(psi) df_z,
  // df_z1 = df0_1 + G13 g,  df_z2 = df0_2 + G23 g   (section 2, at rest)
  f(kDv, kDv + 1) = 2 * e.u3;
  f(kDv, kB + 1) = -e.g;
  f(kDv, kA + 1) = -e.g;
  f(kDv + 1, kDv) = -2 * e.u3;
  f(kDv + 1, kB) = e.g;
  f(kDv + 1, kA) = e.g;
  for (int i = 0; i < 2; ++i) {
    f(kDv + i, kDf0) = a(i, 0);
    f(kDv + i, kDf0 + 1) = a(i, 1);
    f(kDv + i, kG) = a(i, 0) * e.g;
    f(kDv + i, kG + 1) = a(i, 1) * e.g;
  }
  // d(a1)/dt = -dv2/(R_M+h),  d(a2)/dt = dv1/(R_N+h)
  f(kA, kDv + 1) = -1.0 / e.rm;
  f(kA + 1, kDv) = 1.0 / e.rn;
  // d(b1)/dt = u3 b2 - u2 b3 - nu1;  d(b2)/dt = -u3 b1 - nu2;  d(b3)/dt = u2 b1 - nu3
  f(kB, kB + 1) = e.u3;
  f(kB, kB + 2) = -e.u2;
  f(kB + 1, kB) = -e.u3;
  f(kB + 2, kB) = e.u2;
  // nu = A(psi) (nu0 + Theta omega_z),  omega_z = A^T u_x = (u2 s, u2 c, u3) at rest
  // (the true body rate: the true psi)
  const Eigen::Vector3d w = rot(psi).transpose() * Eigen::Vector3d(0, e.u2, e.u3);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      f(kB + i, kNu0 + j) = -a(i, j);
      for (int k = 0; k < 3; ++k) f(kB + i, theta(j + 1, k + 1)) = -a(i, j) * w(k);
    }
  }
  if (nominal != nullptr) {
    // b3 against the nominal's errors: d/db3 of A(psi - b3) v is -A' v,
    // A' = dA/dpsi = [[-s, -c], [c, -s]] on the horizontal
    const auto& p = nominal->params;
    const auto at = [&](int state) { return p[static_cast<std::size_t>(state - kNu0)]; };
    Eigen::Vector3d theta_row;
    Eigen::Vector3d nu_z;
    for (int i = 0; i < 3; ++i) {
      for (int k = 0; k < 3; ++k) theta_row(k) = at(theta(i + 1, k + 1));
      nu_z(i) = at(kNu0 + i) + theta_row.dot(w);
    }
    const Eigen::Vector2d df_z(at(kDf0) + e.g * at(kG), at(kDf0 + 1) + e.g * at(kG + 1));
    const double c = std::cos(psi_c), s = std::sin(psi_c);
    Eigen::Matrix2d da;  // A' on the horizontal
    da << -s, -c, c, -s;
    const Eigen::Vector2d dv_b3 = -da * df_z;
    const Eigen::Vector2d b_b3 = da * nu_z.head<2>();
    for (int i = 0; i < 2; ++i) {
      f(kDv + i, kB + 2) += dv_b3(i);
      f(kB + i, kB + 2) += b_b3(i);
    }
  }
  return f;
}

Discrete discretize_hold(const EarthAt& e, double psi, double dt, const ProcessNoise& noise,
                         const Nominal* nominal, double t_mid_s) {
  // Van Loan: expm([[-F, GQG^T], [0, F^T]] dt) = [[., E12], [0, Phi^T]],
  // Q_d = Phi E12.
  constexpr int n = sx::kN;
  const StateMat f = hold_dynamics(e, psi, nominal, t_mid_s);
  Eigen::Matrix<double, 2 * n, 2 * n> m = Eigen::Matrix<double, 2 * n, 2 * n>::Zero();
  m.topLeftCorner<n, n>() = -f * dt;
  m.topRightCorner<n, n>() = noise_input(noise) * dt;
  m.bottomRightCorner<n, n>() = f.transpose() * dt;
  const Eigen::Matrix<double, 2 * n, 2 * n> em = m.exp();
  Discrete d;
  d.phi = em.bottomRightCorner<n, n>().transpose();
  d.q = d.phi * em.topRightCorner<n, n>();
  d.q = 0.5 * (d.q + d.q.transpose()).eval();
  d.sqrt_q = psd_sqrt(d.q);
  return d;
}

TurnIntegrals turn_integrals(std::span<const AngleSample> samples) {
  // Jc = int Omega^2 cos psi dt = int Omega cos psi dpsi (and Js with sin),
  // midpoint rule on the encoder intervals.
  TurnIntegrals j{0, 0};
  for (std::size_t k = 0; k + 1 < samples.size(); ++k) {
    const double dpsi = samples[k + 1].psi_rad - samples[k].psi_rad;
    const double dt = samples[k + 1].t_s - samples[k].t_s;
    if (dt <= 0) continue;
    const double mid = 0.5 * (samples[k + 1].psi_rad + samples[k].psi_rad);
    const double omega = dpsi / dt;
    j.jc += omega * std::cos(mid) * dpsi;
    j.js += omega * std::sin(mid) * dpsi;
  }
  return j;
}

TurnIntegrals turn_integrals_constant_rate(double psi1, double psi2, double plateau_rate) {
  return {plateau_rate * (std::sin(psi2) - std::sin(psi1)),
          -plateau_rate * (std::cos(psi2) - std::cos(psi1)), plateau_rate};
}

Discrete turn_transition(const EarthAt& e, std::span<const AngleSample> samples,
                         const ProcessNoise& noise, const TurnIntegrals* integrals,
                         const Nominal* nominal) {
  // Only the 7 navigation rows move: the parameters are constants, so each
  // step is [[S_nn, S_np], [0, I]], the product keeps that form, and the
  // noise stays in the navigation block. Per encoder sample that is a few
  // 7x7 and 7x18 products, not four 25x25 ones.
  using namespace sx;
  using NavMat = Eigen::Matrix<double, kNav, kNav>;
  using NavParMat = Eigen::Matrix<double, kNav, kParams>;
  NavMat pnn = NavMat::Identity();
  NavParMat pnp = NavParMat::Zero();
  NavMat qnn = NavMat::Zero();
  const NavMat gqg = noise_input(noise).topLeftCorner<kNav, kNav>();
  const bool closed_rate = integrals != nullptr && std::isfinite(integrals->plateau_rate);
  const bool spread_at_end = integrals != nullptr && !closed_rate;
  for (std::size_t k = 0; k + 1 < samples.size(); ++k) {
    const double dt = samples[k + 1].t_s - samples[k].t_s;
    if (dt <= 0) continue;
    const double psi1 = samples[k].psi_rad, psi2 = samples[k + 1].psi_rad;
    const double t_mid = 0.5 * (samples[k].t_s + samples[k + 1].t_s);
    // Bounded terms of F at the mid angle, second-order transition:
    // I + F dt + (F dt)^2 / 2, whose parameter rows are those of I.
    const StateMat f = hold_dynamics(e, 0.5 * (psi1 + psi2), nominal, t_mid);
    // the angles the computed frame sees the body at (about a nominal:
    // turned by -b3); the turn itself is the true one
    const double psi1c = nominal != nullptr ? psi1 - nominal->b3(samples[k].t_s, psi1) : psi1;
    const double psi2c = nominal != nullptr ? psi2 - nominal->b3(samples[k + 1].t_s, psi2) : psi2;
    const NavMat fnn = f.topLeftCorner<kNav, kNav>() * dt;
    const NavParMat fnp = f.topRightCorner<kNav, kParams>() * dt;
    const NavMat snn = NavMat::Identity() + fnn + 0.5 * fnn * fnn;
    NavParMat snp = fnp + 0.5 * fnn * fnp;
    // Theta_.3 Omega integrates over angle: Delta b = -[int A dpsi] Theta_.3,
    // int A dpsi = [[S, C, 0], [-C, S, 0], [0, 0, psi2 - psi1]].
    const double sd = std::sin(psi2c) - std::sin(psi1c), cd = std::cos(psi2c) - std::cos(psi1c);
    const double ia[3][3] = {{sd, cd, 0}, {-cd, sd, 0}, {0, 0, psi2 - psi1}};
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) snp(kB + i, theta(j + 1, 3) - kNav) -= ia[i][j];
    // the proof-mass jump of this step: Omega cos psi dpsi and Omega sin
    // psi dpsi (midpoint), or the closed form's at its plateau rate
    double jc = 0, js = 0;
    if (!spread_at_end) {
      if (closed_rate) {
        jc = integrals->plateau_rate * sd;
        js = -integrals->plateau_rate * cd;
      } else {
        const double mid = 0.5 * (psi1c + psi2c), dpsi = psi2 - psi1, omega = dpsi / dt;
        jc = omega * std::cos(mid) * dpsi;
        js = omega * std::sin(mid) * dpsi;
      }
    }
    snp(kDv, kR - kNav) += jc;
    snp(kDv, kR + 1 - kNav) += js;
    snp(kDv + 1, kR - kNav) += js;
    snp(kDv + 1, kR + 1 - kNav) -= jc;
    pnp = snn * pnp + snp;
    pnn = snn * pnn;
    qnn = snn * qnn * snn.transpose() + gqg * dt;
  }
  Discrete d{StateMat::Identity(), StateMat::Zero(), StateMat::Zero()};
  d.phi.topLeftCorner<kNav, kNav>() = pnn;
  d.phi.topRightCorner<kNav, kParams>() = pnp;
  if (spread_at_end) {
    // Delta dv1 = r1 Jc + r2 Js, Delta dv2 = r1 Js - r2 Jc, at the end
    d.phi(kDv, kR) += integrals->jc;
    d.phi(kDv, kR + 1) += integrals->js;
    d.phi(kDv + 1, kR) += integrals->js;
    d.phi(kDv + 1, kR + 1) -= integrals->jc;
  }
  d.q.topLeftCorner<kNav, kNav>() = 0.5 * (qnn + qnn.transpose());
  d.sqrt_q = psd_sqrt(d.q);
  return d;
}

XiMat initial_map(const EarthAt& e, double psi_s) {
  using namespace sx;
  XiMat t = XiMat::Zero();
  const Mat3 a = rot(psi_s);
  // dv(t0) = v0
  t(kDv, sxi::kV0) = 1;
  t(kDv + 1, sxi::kV0 + 1) = 1;
  // a1 = -dr_N/(R_M+h), a2 = dr_E/(R_N+h)
  t(kA, sxi::kDrN) = -1.0 / e.rm;
  t(kA + 1, sxi::kDrE) = 1.0 / e.rn;
  // parameters map to themselves
  for (int p = 0; p < kParams; ++p) t(kNu0 + p, sxi::kParams + p) = 1;
  // da(t0) = A(psi_s) (df0_1 + G13 g, df0_2 + G23 g), rows as linear forms in xi
  Eigen::Matrix<double, 2, sxi::kN> da = Eigen::Matrix<double, 2, sxi::kN>::Zero();
  for (int i = 0; i < 2; ++i) {
    da(i, sxi::kParams + (kDf0 - kNu0)) = a(i, 0);
    da(i, sxi::kParams + (kDf0 + 1 - kNu0)) = a(i, 1);
    da(i, sxi::kParams + (kG - kNu0)) = a(i, 0) * e.g;
    da(i, sxi::kParams + (kG + 1 - kNu0)) = a(i, 1) * e.g;
  }
  // b1 = -da2/g - a1 - nbar2/g;  b2 = da1/g - a2 + nbar1/g;  b3 = dpsi0 - tan(lat) a2
  t.row(kB) = -da.row(1) / e.g - t.row(kA);
  t(kB, sxi::kNbar + 1) -= 1.0 / e.g;
  t.row(kB + 1) = da.row(0) / e.g - t.row(kA + 1);
  t(kB + 1, sxi::kNbar) += 1.0 / e.g;
  t.row(kB + 2) = -e.tan_lat * t.row(kA + 1);
  t(kB + 2, sxi::kDpsi0) += 1;
  return t;
}

}  // namespace turncal::est
