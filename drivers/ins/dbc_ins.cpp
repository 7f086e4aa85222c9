// An INS whose output the stand's DBC describes ([ins] and the roles): the
// East and North velocity in navigation axes, in one frame or in two (the
// reference INS, can-icd.md: INS_VelE and INS_VelN paired by their time
// tag), in any unit the DBC names and either sign; timed by a tag in the
// frame, by a separate device time frame, or by the kernel receive time on
// a clock of the nominal rate. INS_Status and INS_Command as the reference.
#include <algorithm>
#include <cmath>
#include <numbers>

#include "turncal/drivers/common.hpp"
#include "turncal/drivers/reference.hpp"

namespace turncal::drivers {

namespace {
constexpr double kDeg = std::numbers::pi / 180;

class DbcIns final : public InsDriver {
 public:
  DbcIns(const InsLayout& layout, const RoleMap& roles, Plausibility p, double east_to_si,
         double north_to_si, TimeScale vel_tag, TimeScale north_tag, TimeScale status_tag,
         TimeScale time_frame)
      : layout_(layout),
        roles_(roles),
        plausible_(p),
        one_frame_(roles[Role::InsVelEast].message == roles[Role::InsVelNorth].message),
        east_to_si_(east_to_si),
        north_to_si_(north_to_si),
        east_scale_(vel_tag),
        north_scale_(north_tag),
        status_scale_(status_tag),
        time_scale_(time_frame),
        vel_tag_(vel_tag.range_us),
        status_tag_(status_tag.range_us),
        time_tag_(time_frame.range_us) {}

  Decoded decode(const FrameView& f) override {
    if (f.status != can::DecodeStatus::Ok) return Decoded{};
    auto is = [&](Role r) { return roles_.has(r) && f.msg == roles_[r].message; };
    auto v = [&](Role r) { return f.values[roles_[r].signal_index]; };
    bool mine = false;
    if (layout_.time == InsTimeSource::TimeFrame && is(Role::InsTime)) {
      const double tag = v(Role::InsTime);
      if (!std::isfinite(tag)) return Decoded::malformed();
      time_s_ = time_tag_(tag * time_scale_.to_us);
      time_host_s_ = f.host_s;
      mine = true;
    }
    const bool east = is(Role::InsVelEast), north = is(Role::InsVelNorth);
    if (east || north) return velocity(f, east, north);
    if (is(Role::InsMode)) {
      double t = NAN;
      if (roles_.has(Role::InsStatusTimeTag)) {
        const double tag = v(Role::InsStatusTimeTag);
        if (!std::isfinite(tag)) return Decoded::malformed();
        if (!plausible_.in_range(*roles_[Role::InsMode].signal, v(Role::InsMode)))
          return Decoded::implausible(kInsStatus);
        t = status_tag_(tag * status_scale_.to_us);
      } else if (!plausible_.in_range(*roles_[Role::InsMode].signal, v(Role::InsMode))) {
        return Decoded::implausible(kInsStatus);
      }
      const double remaining =
          roles_.has(Role::InsAlignRemaining) ? v(Role::InsAlignRemaining) : std::nan("");
      return Decoded::taken(
          kInsStatus, t,
          InsStatusSample{t, f.host_s, static_cast<int>(v(Role::InsMode)), remaining});
    }
    if (is(Role::InsCommand))
      return Decoded::taken(kStreams, NAN, host_command(f, Role::InsCommand));
    return mine ? Decoded::pending() : Decoded{};
  }

  Result<std::vector<can::Frame>> command(const InsCommand& c) const override {
    auto f =
        roles_.encode_checked(Role::InsCommand, {{Role::InsCommand, static_cast<double>(c.code)},
                                                 {Role::InsCommandAlignDuration, c.align_s},
                                                 {Role::InsCommandHeading, c.heading_rad / kDeg},
                                                 {Role::InsCommandSeq, c.seq}});
    if (!f) return f.error();
    return std::vector<can::Frame>{*f};
  }

  [[nodiscard]] SignalSpan align_duration() const override {
    return span_of(roles_, Role::InsCommandAlignDuration, 1);
  }
  [[nodiscard]] std::vector<std::pair<std::uint32_t, bool>> receive_ids() const override {
    return roles_.receive_ids(true);
  }
  [[nodiscard]] std::uint64_t half_pairs() const override { return half_pairs_; }
  [[nodiscard]] std::uint64_t untimed() const override { return untimed_; }

 private:
  Decoded velocity(const FrameView& f, bool east, bool north) {
    auto v = [&](Role r) { return f.values[roles_[r].signal_index]; };
    // a component in SI (the DBC's unit, the layout's sign), or NaN
    auto component = [&](Role r) {
      const double x = v(r);
      const double to_si = r == Role::InsVelEast ? east_to_si_ : north_to_si_;
      return to_si == 1 ? x : x * to_si;
    };
    auto implausible = [&](Role r, double si) {
      return !plausible_.in_range(*roles_[r].signal, v(r)) ||
             !(std::abs(si) <= plausible_.max_velocity_mps);
    };
    if (one_frame_) {
      const double ve = component(Role::InsVelEast), vn = component(Role::InsVelNorth);
      const bool tagged = layout_.time == InsTimeSource::Tag;
      const double tag = tagged ? v(Role::InsVelEastTimeTag) : 0;
      if (!std::isfinite(ve) || !std::isfinite(vn) || !std::isfinite(tag))
        return Decoded::malformed();
      if (implausible(Role::InsVelEast, ve) || implausible(Role::InsVelNorth, vn))
        return Decoded::implausible(kVelocity);
      const double t = sample_time(f.host_s, tag, vel_tag_, east_scale_);
      if (std::isnan(t)) return Decoded::pending();  // untimed: counted, left out
      return Decoded::taken(kVelocity, t, VelocitySample{t, f.host_s, ve, vn});
    }
    // two frames, paired by their time tags (the layout is "tag")
    (void)north;
    const Role role = east ? Role::InsVelEast : Role::InsVelNorth;
    const double value = component(role);
    const double tag = v(east ? Role::InsVelEastTimeTag : Role::InsVelNorthTimeTag);
    if (!std::isfinite(value) || !std::isfinite(tag)) return Decoded::malformed();
    if (implausible(role, value)) return Decoded::implausible(kVelocity);
    // the north tag in the east tag's unit, so the two can be compared
    const double tag_us = tag * (east ? east_scale_.to_us : north_scale_.to_us);
    if (half_pending_ && half_tag_ == tag_us && half_is_east_ != east) {
      half_pending_ = false;
      const double t = vel_tag_(tag_us);
      return Decoded::taken(
          kVelocity, t,
          VelocitySample{t, f.host_s, east ? value : half_value_, east ? half_value_ : value});
    }
    // a half pair left waiting: its sample is lost (the tag gap counts it as dropped)
    if (half_pending_) ++half_pairs_;
    half_pending_ = true;
    half_is_east_ = east;
    half_tag_ = tag_us;
    half_value_ = value;
    return Decoded::pending();
  }

  /// The device time of a one-frame velocity sample, s; NaN: none to give.
  double sample_time(double host_s, double tag, TagUnwrap& unwrap, const TimeScale& scale) {
    switch (layout_.time) {
      case InsTimeSource::Tag:
        return unwrap(tag * scale.to_us);
      case InsTimeSource::TimeFrame: {
        // the time frame just before, each stamping one sample
        const double age = host_s - time_host_s_;
        if (std::isnan(time_s_) ||
            !(age >= 0 && age <= layout_.time_frame_max_age_s * time_scale_s_)) {
          ++untimed_;
          return NAN;
        }
        const double t = time_s_;
        time_s_ = NAN;
        return t;
      }
      case InsTimeSource::Receive:
        return receive_clock(host_s);
    }
    return NAN;
  }

  /// A clock of the nominal rate under the receive times: sample k is due at
  /// anchor + k period, and a frame comes at or after its due time (the
  /// kernel stamps a frame when it is received, so a busy host does not
  /// delay it; the bus and the INS's own send queue can, a little). The
  /// anchor is the least host - k period seen, so the frames that came
  /// soonest fix it, and each frame takes the nearest slot. A frame that
  /// finds its slot taken (the one before it came over half a period late
  /// and took this one's) is left out and counted: better one sample fewer
  /// than every later one a period off. The ingest's clock fit then maps
  /// k period onto the host timeline, as it does a device's own tags.
  double receive_clock(double host_s) {
    const double period = 1 / layout_.velocity_rate_hz;
    if (k_ < 0) {
      k_ = 0;
      anchor_s_ = host_s;
      return 0;
    }
    const auto due = static_cast<long long>(std::llround((host_s - anchor_s_) / period));
    if (due <= k_) {
      ++untimed_;
      return NAN;
    }
    k_ = due;
    anchor_s_ = std::min(anchor_s_, host_s - static_cast<double>(k_) * period);
    return static_cast<double>(k_) * period;
  }

 public:
  /// Real seconds to host seconds (a virtual stand's time scale), for the
  /// time frame's age.
  void set_time_scale(double scale) { time_scale_s_ = scale; }

 private:
  InsLayout layout_;
  const RoleMap& roles_;
  Plausibility plausible_;
  bool one_frame_;
  double east_to_si_, north_to_si_;
  TimeScale east_scale_, north_scale_, status_scale_, time_scale_;
  TagUnwrap vel_tag_, status_tag_, time_tag_;
  double time_scale_s_ = 1;
  // the half of a velocity pair waiting for its other half
  bool half_pending_ = false;
  bool half_is_east_ = false;
  double half_tag_ = 0, half_value_ = 0;
  std::uint64_t half_pairs_ = 0;
  // the last time frame not yet used
  double time_s_ = NAN, time_host_s_ = NAN;
  std::uint64_t untimed_ = 0;
  // the receive-time clock
  long long k_ = -1;
  double anchor_s_ = 0;
};

}  // namespace

std::unique_ptr<InsDriver> make_ins(const InsLayout& layout, const RoleMap& roles,
                                    Plausibility plausibility, double time_scale) {
  // resolve_roles has checked the units: these cannot fail on its RoleMap
  auto speed = [&](Role r, double sign) { return velocity_unit(*roles[r].signal).value() * sign; };
  auto time = [&](Role r) {
    return roles.has(r) ? time_unit(*roles[r].signal).value() : TimeScale{};
  };
  auto d = std::make_unique<DbcIns>(
      layout, roles, plausibility, speed(Role::InsVelEast, layout.east_sign),
      speed(Role::InsVelNorth, layout.north_sign), time(Role::InsVelEastTimeTag),
      time(Role::InsVelNorthTimeTag), time(Role::InsStatusTimeTag), time(Role::InsTime));
  d->set_time_scale(time_scale);
  return d;
}

std::unique_ptr<InsDriver> make_reference_ins(const RoleMap& roles, Plausibility plausibility) {
  return make_ins(InsLayout{}, roles, plausibility, 1);
}

}  // namespace turncal::drivers
