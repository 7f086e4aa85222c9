#include "turncal/drivers/common.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace turncal {

double TagUnwrap::operator()(double tag_us) {
  if (have_ && tag_us < last_ - range_ / 2) wraps_ += range_;
  if (have_ && tag_us > last_ + range_ / 2) wraps_ -= range_;  // a late frame from before a wrap
  have_ = true;
  last_ = tag_us;
  return (tag_us + wraps_) * 1e-6;
}

double AngleUnwrap::operator()(double angle_rad) {
  constexpr double kTwoPi = 2 * std::numbers::pi;
  if (have_) {
    const double step = angle_rad - last_;
    turns_ -= kTwoPi * std::round(step / kTwoPi);
  }
  have_ = true;
  last_ = angle_rad;
  return angle_rad + turns_;
}

Plausibility Plausibility::none() {
  Plausibility p;
  p.max_velocity_mps = std::numeric_limits<double>::infinity();
  p.max_table_rate_rps = std::numeric_limits<double>::infinity();
  p.max_fraction = 1;
  p.dbc_ranges = false;
  return p;
}

bool Plausibility::in_range(const can::Signal& sig, double value) const {
  if (!dbc_ranges) return true;
  if (sig.minimum == 0 && sig.maximum == 0) return true;  // as vendor files write "none"
  // the DBC's range is in its decimal text: a value at its end may differ
  // from it in the last bits
  const double slack = 1e-9 * std::max(std::abs(sig.minimum), std::abs(sig.maximum));
  return value >= sig.minimum - slack && value <= sig.maximum + slack;
}

namespace drivers {

SignalSpan span_of(const RoleMap& roles, Role r, double to_si) {
  const ResolvedRole& rr = roles[r];
  const can::PhysicalRange p = can::physical_range(*rr.signal);
  return {rr.message->name + "." + rr.signal->name, p.lo * to_si, p.hi * to_si,
          can::describe_range(*rr.signal)};
}

HostCommandSample host_command(const FrameView& f, Role r) {
  const std::size_t n = f.msg->signals.size();
  return HostCommandSample{
      f.host_s, r, std::vector<double>(f.values.begin(), f.values.begin() + static_cast<long>(n))};
}

}  // namespace drivers
}  // namespace turncal
