// The state of model.md, section 3: its layout and the parameter table are
// in turncal/estimation/params.hpp; here its vectors and the start's
// independent variables (model.md, 6).
#pragma once

#include <Eigen/Core>

#include "turncal/estimation/params.hpp"

namespace turncal::est {

using StateVec = Eigen::Matrix<double, sx::kN, 1>;
using StateMat = Eigen::Matrix<double, sx::kN, sx::kN>;

/// Independent variables of the start (model.md, 6): x0 = T xi.
namespace sxi {
inline constexpr int kV0 = 0;      ///< dv(t0) East, North, m/s
inline constexpr int kDrE = 2;     ///< position error East, m
inline constexpr int kDrN = 3;     ///< position error North, m
inline constexpr int kDpsi0 = 4;   ///< heading error given at alignment, rad, clockwise from North
inline constexpr int kNbar = 5;    ///< accelerometer noise mean over the alignment, 1 and 2, m/s^2
inline constexpr int kParams = 7;  ///< the 18 parameters, as in the state
inline constexpr int kN = kParams + sx::kParams;
}  // namespace sxi

using XiVec = Eigen::Matrix<double, sxi::kN, 1>;
using XiMat = Eigen::Matrix<double, sx::kN, sxi::kN>;

}  // namespace turncal::est
