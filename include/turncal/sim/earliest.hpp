// The earliest of a device's pending events, as the virtual devices'
// advance loops take them one at a time in simulated time.
#pragma once

#include <cmath>

namespace turncal::stand {

/// The earliest event considered at or before `until`: a NaN time is no
/// event; of events due at the same time the last considered is taken;
/// `which` stays -1 when none is due.
class Earliest {
 public:
  explicit Earliest(double until) : when_(until) {}
  void consider(double at, int id) {
    if (!std::isnan(at) && at <= when_) {
      when_ = at;
      which_ = id;
    }
  }
  [[nodiscard]] double when() const { return when_; }
  [[nodiscard]] int which() const { return which_; }

 private:
  double when_;
  int which_ = -1;
};

}  // namespace turncal::stand
