#include "turncal/estimation/model.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <unsupported/Eigen/MatrixFunctions>

#include "turncal/earth.hpp"

namespace turncal::est {

Eigen::Matrix3d body_to_geographic(double psi) {
  const double c = std::cos(psi), s = std::sin(psi);
  Eigen::Matrix3d a;
  a << c, -s, 0, s, c, 0, 0, 0, 1;
  return a;
}

namespace {

using Mat3 = Eigen::Matrix3d;

/// G Q G^T: accelerometer noise in the dv rows, gyro noise in the b rows
/// (isotropic, so the rotation A(psi) leaves it unchanged).
StateMat noise_input(const ProcessNoise& n) {
  StateMat q = StateMat::Zero();
  q(sx::kDv, sx::kDv) = q(sx::kDv + 1, sx::kDv + 1) = n.q_a;
  for (int i = 0; i < 3; ++i) q(sx::kB + i, sx::kB + i) = n.q_g;
  return q;
}

}  // namespace

namespace {

/// psd_sqrt for any fixed size.
template <int N>
Eigen::Matrix<double, N, N> psd_sqrt_of(const Eigen::Matrix<double, N, N>& q) {
  using Vec = Eigen::Matrix<double, N, 1>;
  using Mat = Eigen::Matrix<double, N, N>;
  // Scaled by its diagonal first: Q spans some 20 orders of magnitude (the
  // a rows see q_a dt^3 / R^2), and an unscaled eigensolver would bury the
  // small blocks in the round-off of the large ones.
  Vec d = q.diagonal().cwiseMax(0.0).cwiseSqrt();
  for (int i = 0; i < N; ++i)
    if (!(d(i) > 0)) d(i) = 1;
  const Mat qs =
      d.cwiseInverse().asDiagonal() * (0.5 * (q + q.transpose())) * d.cwiseInverse().asDiagonal();
  Eigen::SelfAdjointEigenSolver<Mat> es(qs);
  const Vec ev = es.eigenvalues().cwiseMax(0.0).cwiseSqrt();
  return d.asDiagonal() * es.eigenvectors() * ev.asDiagonal();
}

using NavMat = Eigen::Matrix<double, sx::kNav, sx::kNav>;
using NavParMat = Eigen::Matrix<double, sx::kNav, sx::kParams>;

/// The nominal's perturbation coordinates from the model's (see Nominal):
/// (dv, dlat, dlon, psi) = T (dv, a, b), and T^-1.
NavMat to_perturbation(const EarthAt& e) {
  using namespace sx;
  NavMat t = NavMat::Identity();
  t(kA, kA) = -1;                               // dlat = -a1
  t(kA + 1, kA + 1) = 1 / std::cos(e.lat_rad);  // dlon = a2 / cos(lat)
  t(kB, kA) = 1;                                // psi1 = b1 + a1
  t(kB + 1, kA + 1) = 1;                        // psi2 = b2 + a2
  t(kB + 2, kA + 1) = e.tan_lat;                // psi3 = b3 + tan(lat) a2
  return t;
}
NavMat from_perturbation(const EarthAt& e) {
  using namespace sx;
  NavMat t = NavMat::Identity();
  t(kA, kA) = -1;                            // a1 = -dlat
  t(kA + 1, kA + 1) = std::cos(e.lat_rad);   // a2 = cos(lat) dlon
  t(kB, kA) = 1;                             // b1 = psi1 + dlat
  t(kB + 1, kA + 1) = -std::cos(e.lat_rad);  // b2 = psi2 - cos(lat) dlon
  t(kB + 2, kA + 1) = -std::sin(e.lat_rad);  // b3 = psi3 - sin(lat) dlon
  return t;
}

/// F about the nominal's state `n` at orientation psi, still: the INS's
/// error equations with the nominal's velocity, latitude and attitude
/// (the strapdown's mechanization perturbed; the radii's change with
/// latitude, under 1% of the terms it would scale, left out), in the
/// model's coordinates.
StateMat about_nominal(const EarthAt& e, double psi, const NominalState& n,
                       const std::array<double, sx::kParams>& p) {
  using namespace sx;
  using Vec3 = Eigen::Vector3d;
  const double lat = e.lat_rad + n.dlat_rad;
  const double sl = std::sin(lat), cl = std::cos(lat);
  const double rm = earth::meridian_radius_at_sin(sl) + e.height_m;
  const double rn = earth::normal_radius_at_sin(sl) + e.height_m;
  const Vec3 om = earth::kRate * Vec3(0, cl, sl);
  const Vec3 rho(-n.vn / rm, n.ve / rn, n.ve * sl / (cl * rn));
  const Vec3 w_in = om + rho;
  const Vec3 v(n.ve, n.vn, 0);
  const Mat3 c = n.e * body_to_geographic(psi);  // body to the computed frame
  const auto at = [&](int state) { return p[static_cast<std::size_t>(state - kNu0)]; };
  const Vec3 fc = c * Vec3(at(kDf0) + e.g * at(kG), at(kDf0 + 1) + e.g * at(kG + 1), e.g);
  // columns in the perturbation coordinates: the rates of (dv, dlat,
  // dlon, psi) per unit of each
  Eigen::Matrix<double, kNav, kN> fp = Eigen::Matrix<double, kNav, kN>::Zero();
  const auto column = [&](int col, const Vec3& dv_dot, const Vec3& psi_dot) {
    fp.block<2, 1>(kDv, col) += dv_dot.head<2>();  // the vertical channel is held
    fp.block<3, 1>(kB, col) += psi_dot;
  };
  // v_dot = C f + gamma - (2 Omega + rho) x v;  psi_dot = -w_in x psi - C dw + d(w_in)
  const Vec3 cor = 2 * om + rho;
  const Vec3 drho_e(0, 1 / rn, sl / (cl * rn)), drho_n(-1 / rm, 0, 0);
  column(kDv, -cor.cross(Vec3::UnitX()) - drho_e.cross(v), drho_e);
  column(kDv + 1, -cor.cross(Vec3::UnitY()) - drho_n.cross(v), drho_n);
  fp(kA, kDv + 1) = 1 / rm;         // dlat_dot = dvN / R_M
  fp(kA + 1, kDv) = 1 / (rn * cl);  // dlon_dot = dvE / (R_N cos lat) + ...
  const Vec3 dom = earth::kRate * Vec3(0, -sl, cl);
  const Vec3 drho_lat(0, 0, n.ve / (rn * cl * cl));
  column(kA, -(2 * dom + drho_lat).cross(v), dom + drho_lat);
  fp(kA + 1, kA) = n.ve * sl / (rn * cl * cl);
  for (int j = 0; j < 3; ++j) column(kB + j, fc.cross(Vec3::Unit(j)), -w_in.cross(Vec3::Unit(j)));
  // the parameters through the nominal's attitude: the gyros' body rate
  // at rest (the true one), the accelerometers' errors
  const Vec3 w = body_to_geographic(psi).transpose() * Vec3(0, e.u2, e.u3);
  for (int j = 0; j < 3; ++j) {
    column(kNu0 + j, Vec3::Zero(), -c.col(j));
    for (int k = 0; k < 3; ++k) column(theta(j + 1, k + 1), Vec3::Zero(), -c.col(j) * w(k));
  }
  for (int j = 0; j < 2; ++j) {
    column(kDf0 + j, c.col(j), Vec3::Zero());
    column(kG + j, c.col(j) * e.g, Vec3::Zero());
  }
  StateMat f = StateMat::Zero();
  const NavMat back = from_perturbation(e);
  f.topLeftCorner<kNav, kNav>() = back * fp.leftCols<kNav>() * to_perturbation(e);
  f.topRightCorner<kNav, kParams>() = back * fp.rightCols<kParams>();
  return f;
}

}  // namespace

StateMat psd_sqrt(const StateMat& q) {
  return psd_sqrt_of<sx::kN>(q);
}

NominalState Nominal::at(double t_s, std::size_t& hint) const {
  static const std::vector<NominalState> none;  // the state at zero errors
  return sample_at(track ? *track : none, t_s, hint,
                   [](const NominalState& a, const NominalState& b, double f) {
                     NominalState o;
                     o.ve = a.ve + f * (b.ve - a.ve);
                     o.vn = a.vn + f * (b.vn - a.vn);
                     o.dlat_rad = a.dlat_rad + f * (b.dlat_rad - a.dlat_rad);
                     o.e = a.e + f * (b.e - a.e);
                     return o;
                   });
}

EarthAt EarthAt::at(const Site& site) {
  const double lat = site.latitude_rad;
  return EarthAt{earth::normal_gravity(lat, site.height_m),
                 earth::kRate * std::cos(lat),
                 earth::kRate * std::sin(lat),
                 earth::meridian_radius(lat) + site.height_m,
                 earth::normal_radius(lat) + site.height_m,
                 std::tan(lat),
                 lat,
                 site.height_m};
}

StateMat hold_dynamics(const EarthAt& e, double psi, const Nominal* nominal, double t_s) {
  using namespace sx;
  if (nominal != nullptr) return about_nominal(e, psi, nominal->at(t_s), nominal->params);
  StateMat f = StateMat::Zero();
  const Mat3 a = body_to_geographic(psi);
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
  const Eigen::Vector3d w = a.transpose() * Eigen::Vector3d(0, e.u2, e.u3);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      f(kB + i, kNu0 + j) = -a(i, j);
      for (int k = 0; k < 3; ++k) f(kB + i, theta(j + 1, k + 1)) = -a(i, j) * w(k);
    }
  }
  return f;
}

namespace {

/// expm(F dt) and Van Loan's Q_d where only the navigation rows of F are
/// non-zero, on the navigation block alone: [[Phi_nn, W F_np], [0, I]]
/// with [Phi_nn, W] from expm([[F_nn, I], [0, 0]] dt), W = int_0^dt
/// expm(F_nn s) ds, and Q_d from Van Loan's on the block. The same
/// transition as the whole at a fraction of its cost: the second pass
/// makes one every epoch.
Discrete discretize_navigation(const StateMat& f, double dt, const ProcessNoise& noise) {
  constexpr int v = sx::kNav;
  using Block = Eigen::Matrix<double, 2 * v, 2 * v>;
  const NavMat fnn = f.topLeftCorner<v, v>();
  Block m = Block::Zero();
  m.topLeftCorner<v, v>() = fnn * dt;
  m.topRightCorner<v, v>() = NavMat::Identity() * dt;
  const Block ew = m.exp();
  Block vl = Block::Zero();
  vl.topLeftCorner<v, v>() = -fnn * dt;
  vl.topRightCorner<v, v>() = noise_input(noise).topLeftCorner<v, v>() * dt;
  vl.bottomRightCorner<v, v>() = fnn.transpose() * dt;
  const Block eq = vl.exp();
  Discrete d{StateMat::Identity(), StateMat::Zero(), StateMat::Zero()};
  const NavMat phi = ew.topLeftCorner<v, v>();
  d.phi.topLeftCorner<v, v>() = phi;
  d.phi.topRightCorner<v, sx::kParams>() =
      ew.topRightCorner<v, v>() * f.topRightCorner<v, sx::kParams>();
  const NavMat q = phi * eq.topRightCorner<v, v>();
  d.q.topLeftCorner<v, v>() = 0.5 * (q + q.transpose());
  d.sqrt_q.topLeftCorner<v, v>() = psd_sqrt_of<v>(d.q.topLeftCorner<v, v>());
  return d;
}

}  // namespace

Discrete discretize_hold(const EarthAt& e, double psi, double dt, const ProcessNoise& noise,
                         const Nominal* nominal, double t_mid_s) {
  // Van Loan: expm([[-F, GQG^T], [0, F^T]] dt) = [[., E12], [0, Phi^T]],
  // Q_d = Phi E12.
  constexpr int n = sx::kN;
  const StateMat f = hold_dynamics(e, psi, nominal, t_mid_s);
  if (nominal != nullptr) return discretize_navigation(f, dt, noise);
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
  std::size_t hint = SIZE_MAX;  // the nominal's: searched first, then ascending
  for (std::size_t k = 0; k + 1 < samples.size(); ++k) {
    const double dt = samples[k + 1].t_s - samples[k].t_s;
    if (dt <= 0) continue;
    const double psi1 = samples[k].psi_rad, psi2 = samples[k + 1].psi_rad;
    const double t_mid = 0.5 * (samples[k].t_s + samples[k + 1].t_s);
    // Bounded terms of F at the mid angle, second-order transition:
    // I + F dt + (F dt)^2 / 2, whose parameter rows are those of I.
    // About a nominal, F at its state at the step's middle, and the jumps
    // below turned by its attitude E: they are in dv and psi, which are
    // the model's dv and b where a does not move.
    Mat3 e_mid = Mat3::Identity();
    StateMat f;
    if (nominal != nullptr) {
      const NominalState n = nominal->at(t_mid, hint);
      e_mid = n.e;
      f = about_nominal(e, 0.5 * (psi1 + psi2), n, nominal->params);
    } else {
      f = hold_dynamics(e, 0.5 * (psi1 + psi2));
    }
    const NavMat fnn = f.topLeftCorner<kNav, kNav>() * dt;
    const NavParMat fnp = f.topRightCorner<kNav, kParams>() * dt;
    const NavMat snn = NavMat::Identity() + fnn + 0.5 * fnn * fnn;
    NavParMat snp = fnp + 0.5 * fnn * fnp;
    // Theta_.3 Omega integrates over angle: Delta b = -[int A dpsi] Theta_.3,
    // int A dpsi = [[S, C, 0], [-C, S, 0], [0, 0, psi2 - psi1]] (about a
    // nominal -E [int A dpsi] Theta_.3)
    const double sd = std::sin(psi2) - std::sin(psi1), cd = std::cos(psi2) - std::cos(psi1);
    Mat3 ia;
    ia << sd, cd, 0, -cd, sd, 0, 0, 0, psi2 - psi1;
    if (nominal != nullptr) ia = (e_mid * ia).eval();
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) snp(kB + i, theta(j + 1, 3) - kNav) -= ia(i, j);
    // the proof-mass jump of this step: Omega cos psi dpsi and Omega sin
    // psi dpsi (midpoint), or the closed form's at its plateau rate
    double jc = 0, js = 0;
    if (!spread_at_end) {
      if (closed_rate) {
        jc = integrals->plateau_rate * sd;
        js = -integrals->plateau_rate * cd;
      } else {
        const double mid = 0.5 * (psi1 + psi2), dpsi = psi2 - psi1, omega = dpsi / dt;
        jc = omega * std::cos(mid) * dpsi;
        js = omega * std::sin(mid) * dpsi;
      }
    }
    // dv += J (r1, r2), J = [[Jc, Js], [Js, -Jc]], turned by E about a nominal
    Eigen::Matrix2d jump;
    jump << jc, js, js, -jc;
    if (nominal != nullptr) jump = (e_mid.topLeftCorner<2, 2>() * jump).eval();
    snp.block<2, 2>(kDv, kR - kNav) += jump;
    pnp = snn * pnp + snp;
    pnn = snn * pnn;
    qnn = snn * qnn * snn.transpose() + gqg * dt;
  }
  Discrete d{StateMat::Identity(), StateMat::Zero(), StateMat::Zero()};
  d.phi.topLeftCorner<kNav, kNav>() = pnn;
  d.phi.topRightCorner<kNav, kParams>() = pnp;
  if (spread_at_end) {
    // Delta dv1 = r1 Jc + r2 Js, Delta dv2 = r1 Js - r2 Jc, at the end
    Eigen::Matrix2d jump;
    jump << integrals->jc, integrals->js, integrals->js, -integrals->jc;
    if (nominal != nullptr && !samples.empty())
      jump = (nominal->at(samples.back().t_s).e.topLeftCorner<2, 2>() * jump).eval();
    d.phi.block<2, 2>(kDv, kR) += jump;
  }
  d.q.topLeftCorner<kNav, kNav>() = 0.5 * (qnn + qnn.transpose());
  d.sqrt_q = psd_sqrt(d.q);
  return d;
}

XiMat initial_map(const EarthAt& e, double psi_s) {
  using namespace sx;
  XiMat t = XiMat::Zero();
  const Mat3 a = body_to_geographic(psi_s);
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
