#include "turncal/sim/virtual_ins.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace turncal::stand {

VirtualIns::VirtualIns(const InsSetup& setup, const TableMotion& table)
    : setup_(setup), table_(table) {
  out_every_ = std::max(
      1L, static_cast<long>(std::llround(setup.sim.imu_rate_hz / setup.sim.output_rate_hz)));
}

bool VirtualIns::command(double t, const InsCommand& cmd) {
  switch (cmd.code) {
    case InsCommandCode::StartAlignment:
      if (mode_ == InsMode::Fault || !(cmd.align_duration_s > 0)) return false;
      mode_ = InsMode::Aligning;
      align_end_ = t + cmd.align_duration_s;
      align_s_ = cmd.align_duration_s;
      heading_ = cmd.heading_rad;
      nav_.reset();
      t0_ = NAN;
      return true;
    case InsCommandCode::GoIdle:
      if (mode_ == InsMode::Fault) return false;
      mode_ = InsMode::Idle;
      nav_.reset();
      t0_ = NAN;
      return true;
  }
  return false;
}

double VirtualIns::align_remaining(double t) const {
  return mode_ == InsMode::Aligning ? std::max(0.0, align_end_ - t) : 0.0;
}

void VirtualIns::advance(double t, std::vector<InsVelocity>& out) {
  if (mode_ != InsMode::Fault && setup_.fault_at_s <= t) {
    // run up to the fault, then go quiet in fault mode
    const double at = setup_.fault_at_s;
    setup_.fault_at_s = NAN;
    advance(at, out);
    mode_ = InsMode::Fault;
    nav_.reset();
    return;
  }
  if (mode_ == InsMode::Aligning && align_end_ <= t) {
    // The alignment window is history now: the strapdown levels over it and
    // navigates from its end, t0, over the table's commanded motion.
    sim::Config c = setup_.sim;
    c.profile = Profile{};
    c.profile.duration_s = std::numeric_limits<double>::infinity();
    c.profile.align_s = align_s_;
    c.motion = &table_;
    c.motion_t0_s = align_end_;
    c.psi_start_rad = table_.at(align_end_).angle - setup_.heading_offset_rad;
    c.heading_given_rad = heading_;
    nav_ = std::make_unique<sim::Strapdown>(c);
    t0_ = align_end_;
    mode_ = InsMode::Navigating;
    steps_ = 0;
    const sim::VelocitySample v = nav_->output();
    out.push_back({t0_ + v.t_s, v.ve, v.vn});
  }
  if (mode_ != InsMode::Navigating) return;
  const double dt = 1.0 / setup_.sim.imu_rate_hz;
  while (t0_ + nav_->time() + dt <= t + 1e-9 * dt) {
    nav_->step();
    if (++steps_ % out_every_ == 0) {
      const sim::VelocitySample v = nav_->output();
      out.push_back({t0_ + v.t_s, v.ve, v.vn});
    }
  }
}

}  // namespace turncal::stand
