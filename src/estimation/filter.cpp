#include "turncal/estimation/filter.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <cmath>

namespace turncal::est {

MeasMat velocity_measurement() {
  MeasMat h = MeasMat::Zero();
  h(0, sx::kDv) = 1;
  h(1, sx::kDv + 1) = 1;
  return h;
}

namespace {

constexpr int kP = sx::kParams, kV = sx::kNav;

/// Internal order: parameters, then navigation errors.
StateVec to_internal(const StateVec& v) {
  StateVec o;
  o.head<kP>() = v.tail<kP>();
  o.tail<kV>() = v.head<kV>();
  return o;
}

StateVec to_state(const StateVec& o) {
  StateVec v;
  v.head<kV>() = o.tail<kV>();
  v.tail<kP>() = o.head<kP>();
  return v;
}

template <class M>
M rows_to_internal(const M& m) {
  M o(m.rows(), m.cols());
  o.template topRows<kP>() = m.template bottomRows<kP>();
  o.template bottomRows<kV>() = m.template topRows<kV>();
  return o;
}

template <class M>
M cols_to_internal(const M& m) {
  M o(m.rows(), m.cols());
  o.template leftCols<kP>() = m.template rightCols<kP>();
  o.template rightCols<kV>() = m.template leftCols<kV>();
  return o;
}

}  // namespace

SqrtFilter::SqrtFilter(const StateVec& x0, const Eigen::Matrix<double, sx::kN, Eigen::Dynamic>& s0,
                       const StateVec& scale) {
  d_ = to_internal(scale);
  for (int i = 0; i < sx::kN; ++i)
    if (!(d_(i) > 0)) d_(i) = 1;
  x_ = to_internal(x0).cwiseQuotient(d_);
  const Eigen::MatrixXd scaled = d_.cwiseInverse().asDiagonal() * rows_to_internal(s0);
  // Triangularize: S = L with L L^T = scaled scaled^T (QR of scaled^T).
  Eigen::HouseholderQR<Eigen::MatrixXd> qr(scaled.transpose());
  const Eigen::MatrixXd r = qr.matrixQR()
                                .topRows(std::min<Eigen::Index>(scaled.cols(), sx::kN))
                                .triangularView<Eigen::Upper>();
  s_.setZero();
  s_.leftCols(r.rows()) = r.transpose();
}

void SqrtFilter::predict(const StateMat& phi, const StateMat& sqrt_q) {
  // Scaled navigation rows of Phi: [A_p, A_n] in internal column order.
  const Eigen::Matrix<double, kV, 1> dn_inv = d_.tail<kV>().cwiseInverse();
  const Eigen::Matrix<double, kV, kV> an =
      dn_inv.asDiagonal() * phi.topLeftCorner<kV, kV>() * d_.tail<kV>().asDiagonal();
  const Eigen::Matrix<double, kV, kP> ap =
      dn_inv.asDiagonal() * phi.topRightCorner<kV, kP>() * d_.head<kP>().asDiagonal();
  x_.tail<kV>() = (ap * x_.head<kP>() + an * x_.tail<kV>()).eval();
  // [[S_pp, 0], [A_p S_pp + A_n S_np, A_n S_nn, Q_n^1/2]]: only the last
  // block row needs re-triangularizing.
  s_.bottomLeftCorner<kV, kP>() = (ap * s_.topLeftCorner<kP, kP>().triangularView<Eigen::Lower>() +
                                   an * s_.bottomLeftCorner<kV, kP>())
                                      .eval();
  Eigen::Matrix<double, kV + sx::kN, kV> pre;
  pre.topRows<kV>() =
      (an * s_.bottomRightCorner<kV, kV>().triangularView<Eigen::Lower>()).transpose();
  pre.bottomRows<sx::kN>() = (dn_inv.asDiagonal() * sqrt_q.topRows<kV>()).transpose();
  Eigen::HouseholderQR<Eigen::Matrix<double, kV + sx::kN, kV>> qr(pre);
  s_.bottomRightCorner<kV, kV>() =
      qr.matrixQR().topRows<kV>().triangularView<Eigen::Upper>().toDenseMatrix().transpose();
}

UpdateResult SqrtFilter::update(const Meas& z, const MeasMat& h, double sigma_z) {
  constexpr int n = sx::kN;
  const MeasMat hs = cols_to_internal(h) * d_.asDiagonal();  // H in scaled internal coordinates
  UpdateResult res;
  res.innovation = z - hs * x_;
  // The array [[R^1/2, H S], [0, S]] is brought to [[Re^1/2, 0], [Kbar, S+]]
  // by rotating each state column, from the last, against the two
  // measurement columns (u). Column j of S and the fill of u are zero above
  // row j, so every rotation touches rows j.. only and S stays triangular.
  Eigen::Matrix2d ut = sigma_z * Eigen::Matrix2d::Identity();
  Eigen::Matrix<double, n, 2> ub = Eigen::Matrix<double, n, 2>::Zero();
  MeasMat top = hs * s_;
  StateMat sp = s_;
  for (int j = n - 1; j >= 0; --j) {
    for (int r = 0; r < 2; ++r) {
      const double a = ut(r, r), b = top(r, j);
      if (b == 0) continue;
      const double rr = std::hypot(a, b);
      const double c = a / rr, s = b / rr;
      for (int i = 0; i < 2; ++i) {
        const double u = ut(i, r), v = top(i, j);
        ut(i, r) = c * u + s * v;
        top(i, j) = -s * u + c * v;
      }
      for (int i = j; i < n; ++i) {
        const double u = ub(i, r), v = sp(i, j);
        ub(i, r) = c * u + s * v;
        sp(i, j) = -s * u + c * v;
      }
    }
  }
  res.innovation_cov = ut * ut.transpose();
  if (!(ut(0, 0) > 0 && ut(1, 1) > 0) || !ut.allFinite() || !ub.allFinite()) {
    res.ok = false;  // degraded (e.g. a zero measurement noise): keep the prior, report it
    return res;
  }
  s_ = sp;
  // K = Kbar Re^-1/2;  x+ = x + K nu
  x_ += ub * ut.triangularView<Eigen::Lower>().solve(res.innovation);
  return res;
}

StateVec SqrtFilter::state() const {
  return to_state(x_.cwiseProduct(d_));
}

StateMat SqrtFilter::covariance() const {
  const StateMat si = d_.asDiagonal() * s_;
  StateMat st;  // rows in state order
  st.topRows<kV>() = si.bottomRows<kV>();
  st.bottomRows<kP>() = si.topRows<kP>();
  return st * st.transpose();
}

StateVec SqrtFilter::sigma() const {
  return to_state((d_.asDiagonal() * s_).rowwise().norm());
}

JosephFilter::JosephFilter(const StateVec& x0, const StateMat& p0)
    : x_(x0.cast<long double>()), p_(p0.cast<long double>()) {}

void JosephFilter::predict(const StateMat& phi, const StateMat& q) {
  const LMat f = phi.cast<long double>();
  x_ = f * x_;
  p_ = f * p_ * f.transpose() + q.cast<long double>();
  p_ = (0.5L * (p_ + p_.transpose())).eval();
}

UpdateResult JosephFilter::update(const Meas& z, const MeasMat& h, double sigma_z) {
  using LH = Eigen::Matrix<long double, 2, sx::kN>;
  using L2 = Eigen::Matrix<long double, 2, 2>;
  const LH hl = h.cast<long double>();
  const L2 r =
      L2::Identity() * static_cast<long double>(sigma_z) * static_cast<long double>(sigma_z);
  const Eigen::Matrix<long double, 2, 1> nu = z.cast<long double>() - hl * x_;
  const L2 s = hl * p_ * hl.transpose() + r;
  const Eigen::Matrix<long double, sx::kN, 2> k = p_ * hl.transpose() * s.inverse();
  x_ += k * nu;
  const LMat ikh = LMat::Identity() - k * hl;
  p_ = ikh * p_ * ikh.transpose() + k * r * k.transpose();
  p_ = (0.5L * (p_ + p_.transpose())).eval();
  UpdateResult res;
  res.innovation = nu.cast<double>();
  res.innovation_cov = s.cast<double>();
  return res;
}

}  // namespace turncal::est
