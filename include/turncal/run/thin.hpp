// Thinning of a long series for a line drawing: of each half-pixel column,
// the lowest and the highest point, in time order. A one-hour record at
// 100 Hz draws as what it is from a few thousand points, and is never
// copied whole to be drawn.
#pragma once

#include <cmath>
#include <utility>
#include <vector>

namespace turncal::run {

/// A horizontal axis: [x0, x1] drawn from `left` over `width` pixels.
struct Axis {
  double x0, x1, left, width;
  /// The half-pixel column that x falls in.
  [[nodiscard]] long column(double x) const {
    return std::lround((left + (x - x0) / (x1 - x0) * width) * 2);
  }
};

/// Fed point by point in x order; keeps per column the first lowest and the
/// first highest finite point (one, if they are the same), and the first
/// and the last finite point, so that a plot's axis, taken from the points,
/// is the one the series would give whole.
class Thinned {
 public:
  explicit Thinned(Axis axis) : axis_(axis) {}
  void add(double x, double y) {
    if (!std::isfinite(y)) return;
    const long c = axis_.column(x);
    if (!open_) keep({x, y});  // the first point
    last_ = {x, y};
    if (!open_ || c != col_) {
      flush();
      open_ = true;
      col_ = c;
      lo_ = hi_ = {x, y};
    } else if (y < lo_.y) {
      lo_ = {x, y};
    } else if (y > hi_.y) {
      hi_ = {x, y};
    }
  }
  /// The points kept, x and y; the thinning starts afresh.
  std::pair<std::vector<double>, std::vector<double>> take() {
    flush();
    if (open_) keep(last_);
    open_ = false;
    return {std::exchange(x_, {}), std::exchange(y_, {})};
  }

 private:
  struct Point {
    double x, y;
  };
  void flush() {
    if (!open_) return;
    const bool lo_first = lo_.x <= hi_.x;
    const Point a = lo_first ? lo_ : hi_, b = lo_first ? hi_ : lo_;
    keep(a);
    if (b.y != a.y) keep(b);  // equal: the one point is the lowest and the highest
  }
  /// Appends p unless it is the point kept last (the first point of the
  /// series can also be its column's lowest or highest).
  void keep(Point p) {
    if (!x_.empty() && x_.back() == p.x && y_.back() == p.y) return;
    x_.push_back(p.x);
    y_.push_back(p.y);
  }
  Axis axis_;
  bool open_ = false;  ///< a point was added since the last take
  long col_ = 0;
  Point lo_{}, hi_{}, last_{};
  std::vector<double> x_, y_;
};

}  // namespace turncal::run
