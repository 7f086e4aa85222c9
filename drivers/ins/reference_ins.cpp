// The reference INS (can-icd.md): INS_VelE and INS_VelN, one component a
// frame, paired by their time tag; INS_Status; INS_Command.
#include <cmath>
#include <numbers>

#include "turncal/drivers/reference.hpp"
#include "turncal/drivers/common.hpp"

namespace turncal::drivers {

namespace {
constexpr double kDeg = std::numbers::pi / 180;

class ReferenceIns final : public InsDriver {
 public:
  ReferenceIns(const RoleMap& roles, Plausibility p) : roles_(roles), plausible_(p) {}

  Decoded decode(const FrameView& f) override {
    if (f.status != can::DecodeStatus::Ok) return Decoded{};
    auto is = [&](Role r) { return f.msg == roles_[r].message; };
    auto v = [&](Role r) { return f.values[roles_[r].signal_index]; };
    const bool east = is(Role::InsVelEast), north = is(Role::InsVelNorth);
    if (east || north) {
      const Role role = east ? Role::InsVelEast : Role::InsVelNorth;
      const double value = v(role);
      const double tag = v(east ? Role::InsVelEastTimeTag : Role::InsVelNorthTimeTag);
      if (!std::isfinite(value) || !std::isfinite(tag)) return Decoded::malformed();
      if (!plausible_.in_range(*roles_[role].signal, value) ||
          !(std::abs(value) <= plausible_.max_velocity_mps))
        return Decoded::implausible(kVelocity);
      if (half_pending_ && half_tag_ == tag && half_is_east_ != east) {
        half_pending_ = false;
        const double t = vel_tag_(tag);
        return Decoded::taken(kVelocity, t,
                VelocitySample{t, f.host_s, east ? value : half_value_,
                               east ? half_value_ : value});
      }
      // a half pair left waiting: its sample is lost (the tag gap counts it as dropped)
      if (half_pending_) ++half_pairs_;
      half_pending_ = true;
      half_is_east_ = east;
      half_tag_ = tag;
      half_value_ = value;
      return Decoded::pending();
    }
    if (is(Role::InsMode)) {
      const double tag = v(Role::InsStatusTimeTag);
      if (!std::isfinite(tag)) return Decoded::malformed();
      if (!plausible_.in_range(*roles_[Role::InsMode].signal, v(Role::InsMode)))
        return Decoded::implausible(kInsStatus);
      const double t = status_tag_(tag);
      return Decoded::taken(kInsStatus, t,
              InsStatusSample{t, f.host_s, static_cast<int>(v(Role::InsMode)),
                              v(Role::InsAlignRemaining)});
    }
    if (is(Role::InsCommand)) return Decoded::taken(kStreams, NAN, host_command(f, Role::InsCommand));
    return Decoded{};
  }

  Result<std::vector<can::Frame>> command(const InsCommand& c) const override {
    auto f = roles_.encode_checked(Role::InsCommand,
                                   {{Role::InsCommand, static_cast<double>(c.code)},
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

 private:
  const RoleMap& roles_;
  Plausibility plausible_;
  TagUnwrap vel_tag_, status_tag_;
  // the half of a velocity pair waiting for its other half
  bool half_pending_ = false;
  bool half_is_east_ = false;
  double half_tag_ = 0, half_value_ = 0;
  std::uint64_t half_pairs_ = 0;
};

}  // namespace

std::unique_ptr<InsDriver> make_reference_ins(const RoleMap& roles, Plausibility plausibility) {
  return std::make_unique<ReferenceIns>(roles, plausibility);
}

}  // namespace turncal::drivers
