// The nonlinear nominal of the second pass (model.md, 8): the velocity the
// INS would output, noise-free, if its errors were the given parameters,
// from the nonlinear strapdown simulation (src/sim) driven by the recorded
// table motion. It joins the estimation core, which never depends on the
// simulation, to the simulation, which shares no code with the model.
#pragma once

#include <array>
#include <vector>

#include "turncal/estimation/estimator.hpp"
#include "turncal/physics/strapdown.hpp"
#include "turncal/result.hpp"

namespace turncal::est {

using ParamArray = std::array<double, sx::kParams>;

/// The simulation's sensor errors of the 18 parameters (SI, state order),
/// and back: the one place the parameter table meets the strapdown's
/// terms.
sim::SensorErrors sensor_errors(const ParamArray& params);
ParamArray params_of(const sim::SensorErrors& e);

/// The INS velocity over the run with the parameters `params` (SI, state
/// order) injected and the start errors at their prior mean (zero): the
/// simulated IMU on the still base, turned by the recorded encoder angle
/// (linear between samples in each turn window, still in the holds),
/// levelled over the alignment as the INS does (in.priors.align_s), its
/// heading and position given without error. The velocity at the
/// simulation's output rate (100 Hz) from t0 to the end of the timeline,
/// the navigation state at kNominalTrackRateHz.
Result<NominalRun> strapdown_nominal(const EstimationInput& in,
                                     const std::array<double, sx::kParams>& params);

/// The nominal's navigation state's rate, Hz: it moves smoothly (its
/// velocity with the Schuler period, its azimuth with the table at most
/// by Theta_33 times the angle), and the model takes it linear between
/// samples.
inline constexpr double kNominalTrackRateHz = 10;

}  // namespace turncal::est
