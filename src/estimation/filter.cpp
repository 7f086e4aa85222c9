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

SqrtFilter::SqrtFilter(const StateVec& x0, const Eigen::Matrix<double, sx::kN, Eigen::Dynamic>& s0,
                       const StateVec& scale) {
  d_ = scale;
  for (int i = 0; i < sx::kN; ++i)
    if (!(d_(i) > 0)) d_(i) = 1;
  x_ = x0.cwiseQuotient(d_);
  const Eigen::Matrix<double, sx::kN, Eigen::Dynamic> scaled = d_.cwiseInverse().asDiagonal() * s0;
  // Triangularize: S = L with L L^T = scaled scaled^T (QR of scaled^T).
  Eigen::HouseholderQR<Eigen::MatrixXd> qr(scaled.transpose());
  const Eigen::MatrixXd r = qr.matrixQR()
                                .topRows(std::min<Eigen::Index>(scaled.cols(), sx::kN))
                                .triangularView<Eigen::Upper>();
  s_.setZero();
  s_.leftCols(r.rows()) = r.transpose();
}

void SqrtFilter::predict(const StateMat& phi, const StateMat& sqrt_q) {
  // P' = Phi P Phi^T + Q  <=>  S' S'^T = [Phi S, Q^1/2][Phi S, Q^1/2]^T
  const StateMat phi_s = d_.cwiseInverse().asDiagonal() * phi * d_.asDiagonal();
  x_ = phi_s * x_;
  Eigen::Matrix<double, 2 * sx::kN, sx::kN> pre;
  pre.topRows<sx::kN>() = (phi_s * s_).transpose();
  pre.bottomRows<sx::kN>() = (d_.cwiseInverse().asDiagonal() * sqrt_q).transpose();
  Eigen::HouseholderQR<Eigen::Matrix<double, 2 * sx::kN, sx::kN>> qr(pre);
  s_ = qr.matrixQR().topRows<sx::kN>().triangularView<Eigen::Upper>().toDenseMatrix().transpose();
}

UpdateResult SqrtFilter::update(const Meas& z, const MeasMat& h, double sigma_z) {
  constexpr int m = 2, n = sx::kN;
  const MeasMat hs = h * d_.asDiagonal();  // H in scaled coordinates
  UpdateResult res;
  res.innovation = z - hs * x_;
  // [[R^1/2, H S], [0, S]] Theta = [[Re^1/2, 0], [Kbar, S+]]
  Eigen::Matrix<double, m + n, m + n> pre = Eigen::Matrix<double, m + n, m + n>::Zero();
  pre.topLeftCorner<m, m>() = sigma_z * Eigen::Matrix2d::Identity();
  pre.topRightCorner<m, n>() = hs * s_;
  pre.bottomRightCorner<n, n>() = s_;
  Eigen::HouseholderQR<Eigen::Matrix<double, m + n, m + n>> qr(pre.transpose());
  const Eigen::Matrix<double, m + n, m + n> post =
      qr.matrixQR().triangularView<Eigen::Upper>().toDenseMatrix().transpose();
  const Eigen::Matrix2d re_half = post.topLeftCorner<m, m>();
  res.innovation_cov = re_half * re_half.transpose();
  if (!(std::fabs(re_half.determinant()) > 0) || !re_half.allFinite()) {
    res.ok = false;  // degraded: keep the prior, report it
    return res;
  }
  const Eigen::Matrix<double, n, m> kbar = post.bottomLeftCorner<n, m>();
  // K = Kbar Re^-1/2;  x+ = x + K nu
  x_ += kbar * re_half.triangularView<Eigen::Lower>().solve(res.innovation);
  s_ = post.bottomRightCorner<n, n>();
  return res;
}

StateVec SqrtFilter::state() const {
  return x_.cwiseProduct(d_);
}

StateMat SqrtFilter::covariance() const {
  const StateMat s = d_.asDiagonal() * s_;
  return s * s.transpose();
}

StateVec SqrtFilter::sigma() const {
  return (d_.asDiagonal() * s_).rowwise().norm();
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
