#include "turncal/sim/virtual_table.hpp"

#include <algorithm>

#include "turncal/sim/earliest.hpp"

namespace turncal::stand {

VirtualTable::VirtualTable(const TableLimits& limits, double angle0_rad, const TableFaults& faults)
    : lim_(limits), faults_(faults), motion_(angle0_rad) {}

bool VirtualTable::refuse() {
  fault_ = fault_ == TableFault::None ? TableFault::Refused : fault_;
  return false;
}

void VirtualTable::accept(std::uint8_t seq) {
  ack_ = seq;
  if (fault_ == TableFault::Refused) fault_ = TableFault::None;
}

bool VirtualTable::start_move(double t, double delta, double rate) {
  const double a = lim_.max_accel_rps2;
  if (delta != 0) delta += delta > 0 ? faults_.off_target_rad : -faults_.off_target_rad;
  if (faults_.overshoot_rad > 0 && delta != 0) {
    const double os = std::copysign(faults_.overshoot_rad, delta);
    const auto first = motion_.move_by(t, delta + os, rate, a);
    rest_at_ = motion_.move_by(first.t_end, -os, rate, a).t_end;
  } else if (delta != 0) {
    rest_at_ = motion_.move_by(t, delta, rate, a).t_end;
  } else {
    rest_at_ = t;
  }
  state_ = TableState::Moving;
  after_rest_ = TableState::InPosition;
  move_started_ = t;
  if (!std::isnan(faults_.stall_after_s)) {
    stall_at_ = t + faults_.stall_after_s;
    faults_.stall_after_s = NAN;  // once
  }
  return true;
}

void VirtualTable::halt(double t, double decel, TableState then, TableFault why) {
  rest_at_ = motion_.stop(t, decel);
  stall_at_ = NAN;
  if (then == TableState::InPosition) {
    state_ = TableState::Moving;  // until at rest
  } else {
    state_ = then;
  }
  after_rest_ = then;
  if (why != TableFault::None) fault_ = why;
}

bool VirtualTable::command(double t, const TableCommand& cmd) {
  const bool at_rest = t >= rest_at_;
  const bool ready = at_rest && (state_ == TableState::Holding || state_ == TableState::InPosition);
  switch (cmd.code) {
    case TableCommandCode::Enable:
      if (state_ == TableState::Holding || state_ == TableState::InPosition) break;
      if (!at_rest || state_ == TableState::Moving) return refuse();
      state_ = after_rest_ = TableState::Holding;
      fault_ = TableFault::None;  // enabling resets a fault, as drives do
      break;
    case TableCommandCode::Disable:
      if (!at_rest || state_ == TableState::Moving) return refuse();
      state_ = after_rest_ = TableState::Disabled;
      break;
    case TableCommandCode::MoveAbsolute:
    case TableCommandCode::MoveRelative: {
      if (!ready) return refuse();
      if (!(cmd.rate_limit_rps > 0) || cmd.rate_limit_rps > lim_.max_rate_rps * (1 + 1e-9))
        return refuse();
      const double from = motion_.at(t).angle;
      const double target =
          cmd.code == TableCommandCode::MoveAbsolute ? cmd.target_rad : from + cmd.target_rad;
      if (!(target >= lim_.angle_min_rad && target <= lim_.angle_max_rad)) return refuse();
      start_move(t, target - from, cmd.rate_limit_rps);
      break;
    }
    case TableCommandCode::ControlledStop:
      if (state_ == TableState::Moving)
        halt(t, lim_.max_accel_rps2, TableState::InPosition, TableFault::None);
      break;
    case TableCommandCode::QuickStop:
      halt(t, lim_.quick_decel_rps2, TableState::QuickStopped, TableFault::None);
      break;
    default:
      return refuse();
  }
  accept(cmd.seq);
  return true;
}

void VirtualTable::heartbeat(double t) {
  last_heartbeat_ = t;
}

void VirtualTable::advance(double t) {
  for (;;) {
    // the earliest pending event at or before t
    Earliest next(t);
    const auto consider = [&](double at, int id) { next.consider(at, id); };
    if (state_ == TableState::Moving) {
      consider(std::max(last_heartbeat_ + lim_.heartbeat_timeout_s, move_started_), 0);
      consider(stall_at_, 1);
      consider(faults_.drive_fault_at_s, 2);
      consider(rest_at_, 3);
    } else {
      consider(faults_.drive_fault_at_s, 2);
      if (next.when() >= rest_at_) consider(faults_.drift_at_s, 4);
    }
    const double when = next.when();
    switch (next.which()) {
      case 0:
        halt(when, lim_.quick_decel_rps2, TableState::QuickStopped, TableFault::HeartbeatLost);
        break;
      case 1:
        halt(when, lim_.max_accel_rps2, TableState::Fault, TableFault::Stall);
        break;
      case 2:
        faults_.drive_fault_at_s = NAN;
        halt(when, lim_.quick_decel_rps2, TableState::Fault, TableFault::Drive);
        break;
      case 3:
        state_ = after_rest_;
        break;
      case 4:  // the state stays what it was: the drive does not know
        faults_.drift_at_s = NAN;
        rest_at_ =
            motion_.move_by(when, faults_.drift_rad, 0.017453292519943295, lim_.max_accel_rps2)
                .t_end;
        break;
      default:
        now_ = t;
        return;
    }
  }
}

TableStatus VirtualTable::status(double t) const {
  return {state_, ack_, fault_, motion_.at(t).rate};
}

}  // namespace turncal::stand
