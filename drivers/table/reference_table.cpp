// The reference stand's table (can-icd.md): TBL_Encoder (a wrapping angle
// with the table clock's time tag), TBL_Status, TBL_Command with its
// sequence number acknowledged in TBL_Status, and HOST_Heartbeat.
#include <cmath>
#include <numbers>

#include "turncal/drivers/common.hpp"
#include "turncal/drivers/reference.hpp"

namespace turncal::drivers {

namespace {
constexpr double kDeg = std::numbers::pi / 180;

bool is_move(TableCommandCode c) {
  return c == TableCommandCode::MoveAbsolute || c == TableCommandCode::MoveRelative;
}

class ReferenceTable final : public TableDriver {
 public:
  ReferenceTable(const RoleMap& roles, Plausibility p) : roles_(roles), plausible_(p) {}

  Decoded decode(const FrameView& f) override {
    if (f.status != can::DecodeStatus::Ok) return Decoded{};
    auto is = [&](Role r) { return f.msg == roles_[r].message; };
    auto v = [&](Role r) { return f.values[roles_[r].signal_index]; };
    auto in_range = [&](Role r) { return plausible_.in_range(*roles_[r].signal, v(r)); };
    if (is(Role::EncoderAngle)) {
      const double tag = v(Role::EncoderTimeTag);
      const double angle = v(Role::EncoderAngle);
      if (!std::isfinite(tag) || !std::isfinite(angle)) return Decoded::malformed();
      if (!in_range(Role::EncoderAngle)) return Decoded::implausible(kEncoder);
      // unwrapped on copies: the ingest keeps the sample (accept_encoder)
      // only when its step is one the table can make
      pending_tags_ = enc_tag_;
      pending_angle_ = angle_;
      const double t = pending_tags_(tag);
      const double a = pending_angle_(angle * std::numbers::pi / 180);
      return Decoded::taken(kEncoder, t, EncoderSample{t, f.host_s, a});
    }
    if (is(Role::TableState)) {
      if (!in_range(Role::TableState) || !in_range(Role::TableRate))
        return Decoded::implausible(kTableStatus);
      const int fault = static_cast<int>(v(Role::TableFault));
      std::string name = "fault " + std::to_string(fault);
      const auto& table = roles_[Role::TableFault].signal->values;
      if (auto it = table.find(fault); it != table.end()) name = it->second;
      return Decoded::taken(kTableStatus, NAN,
                            TableStatusSample{f.host_s, static_cast<int>(v(Role::TableState)),
                                              static_cast<int>(v(Role::TableAck)), fault, name,
                                              v(Role::TableRate) * std::numbers::pi / 180});
    }
    for (Role r : {Role::TableCommand, Role::HeartbeatCounter})
      if (is(r)) return Decoded::taken(kStreams, NAN, host_command(f, r));
    return Decoded{};
  }

  void accept_encoder() override {
    enc_tag_ = pending_tags_;
    angle_ = pending_angle_;
  }

  [[nodiscard]] double angle_resolution_rad() const override {
    return std::abs(roles_[Role::EncoderAngle].signal->factor) * std::numbers::pi / 180;
  }

  Result<std::vector<can::Frame>> command(const TableCommand& t) override {
    auto f = is_move(t.code)
                 ? roles_.encode_checked(Role::TableCommand,
                                         {{Role::TableCommand, static_cast<double>(t.code)},
                                          {Role::TableCommandSeq, t.seq},
                                          {Role::TableCommandTarget, t.target_rad / kDeg},
                                          {Role::TableCommandRateLimit, t.rate_rps / kDeg}})
                 : roles_.encode_checked(Role::TableCommand,
                                         {{Role::TableCommand, static_cast<double>(t.code)},
                                          {Role::TableCommandSeq, t.seq}});
    if (!f) return f.error();
    return std::vector<can::Frame>{*f};
  }

  [[nodiscard]] std::vector<can::Frame> heartbeat(std::uint8_t counter,
                                                  int host_state) const override {
    return {roles_.encode(Role::HeartbeatCounter,
                          {{Role::HeartbeatCounter, counter}, {Role::HeartbeatState, host_state}})};
  }

  [[nodiscard]] SignalSpan target() const override {
    return span_of(roles_, Role::TableCommandTarget, kDeg);
  }
  [[nodiscard]] SignalSpan rate_limit() const override {
    return span_of(roles_, Role::TableCommandRateLimit, kDeg);
  }
  [[nodiscard]] std::vector<std::pair<std::uint32_t, bool>> receive_ids() const override {
    return roles_.receive_ids(false);
  }

 private:
  const RoleMap& roles_;
  Plausibility plausible_;
  TagUnwrap enc_tag_, pending_tags_;
  AngleUnwrap angle_, pending_angle_;
};

}  // namespace

std::unique_ptr<TableDriver> make_reference_table(const RoleMap& roles, Plausibility plausibility) {
  return std::make_unique<ReferenceTable>(roles, plausibility);
}

}  // namespace turncal::drivers
