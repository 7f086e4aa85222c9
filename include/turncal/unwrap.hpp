// Device counters into continuous quantities: wrapping time tags and
// wrapping angles.
#pragma once

namespace turncal {

/// A wrapping unsigned microsecond time tag (u32 in the ICD) into
/// seconds on a continuous device clock. A step back of more than half the
/// range is a wrap; a smaller step back is taken as it is (out of order).
class TagUnwrap {
 public:
  explicit TagUnwrap(double range_us = 4294967296.0) : range_(range_us) {}
  double operator()(double tag_us);

 private:
  double range_;
  bool have_ = false;
  double last_ = 0;
  double wraps_ = 0;
};

/// A wrapping angle (rad) into a continuous multi-turn angle: each step
/// taken as the shortest way round.
class AngleUnwrap {
 public:
  double operator()(double angle_rad);

 private:
  bool have_ = false;
  double last_ = 0;
  double turns_ = 0;
};

}  // namespace turncal
