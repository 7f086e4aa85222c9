#include "turncal/sim/virtual_stand.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace turncal::stand {
namespace {

constexpr double kDeg = 0.017453292519943295;
constexpr double kTwoPi = 6.283185307179586;

/// A standard ID the database does not define, for garbage and floods.
std::uint32_t unknown_id(const can::FrameCodec& codec) {
  for (std::uint32_t id = 0x7FF; id > 0; --id) {
    can::Frame f;
    f.id = id;
    if (codec.message_for(f) == nullptr) return id;
  }
  return 0x7FF;
}

}  // namespace

std::uint32_t DeviceClock::tag(double t) const {
  const double us = std::floor(read(t) * 1e6);
  const double wrapped = us - 4294967296.0 * std::floor(us / 4294967296.0);
  return static_cast<std::uint32_t>(wrapped);
}

double DeviceClock::tag_value(double t, const TimeScale& scale, double factor) const {
  const double us = std::floor(read(t) * 1e6);
  const double wrapped =
      std::isfinite(scale.range_us) ? us - scale.range_us * std::floor(us / scale.range_us) : us;
  return std::floor(wrapped / scale.to_us / factor) * factor;
}

VirtualStand::VirtualStand(const StandSetup& setup, const can::Database& db, const RoleMap& roles)
    : setup_(setup),
      db_(db),
      roles_(roles),
      codec_(db),
      table_(setup.table_limits, setup.table_angle0_rad, setup.table_faults),
      drive_([&]() -> std::optional<VirtualDrive402> {
        if (!setup.cia402) return std::nullopt;
        Drive402Setup d = setup.drive;
        d.angle0_rad = setup.table_angle0_rad;
        return std::optional<VirtualDrive402>(std::in_place, d, setup.drive_faults);
      }()),
      ins_(setup.ins, drive_ ? drive_->motion() : table_.motion()),
      rng_(setup.seed) {}

double VirtualStand::role_value(Role r, std::span<const double> values) const {
  return values[roles_[r].signal_index];
}

can::Frame VirtualStand::encode(Role any_role_of_message,
                                std::span<const std::pair<Role, double>> values) {
  const can::Message& m = *roles_[any_role_of_message].message;
  scratch_.assign(m.signals.size(), 0.0);
  for (std::size_t i = 0; i < m.signals.size(); ++i)
    if (m.signals[i].name == "Counter") scratch_[i] = ins_counter_;  // rolling, not a role
  for (const auto& [role, v] : values)
    if (roles_.has(role)) scratch_[roles_[role].signal_index] = v;
  return can::FrameCodec::encode(m, scratch_);
}

bool VirtualStand::ins_quiet(double t) const {
  const StandFaults& f = setup_.faults;
  if (t >= f.ins_silent_at_s) return true;
  return t >= f.ins_burst_at_s && t < f.ins_burst_at_s + f.ins_burst_s;
}

double VirtualStand::ins_tag(Role r, double t) const {
  if (!roles_.has(r)) return 0;
  return setup_.ins_clock.tag_value(t, time_unit(*roles_[r].signal).value(),
                                    roles_[r].signal->factor);
}

void VirtualStand::emit_ins_status(double t, std::vector<StandFrame>& out) {
  if (ins_quiet(t)) {
    ++counts_.dropped;
    return;
  }
  const std::pair<Role, double> v[] = {
      {Role::InsMode, static_cast<double>(ins_.mode())},
      {Role::InsAlignRemaining, std::ceil(ins_.align_remaining(t))},
      {Role::InsStatusTimeTag, ins_tag(Role::InsStatusTimeTag, t)}};
  out.push_back({t, true, encode(Role::InsMode, v)});
  ++ins_counter_;
}

void VirtualStand::emit_velocity(const InsVelocity& s, std::vector<StandFrame>& out) {
  const InsLayout& layout = setup_.ins_layout;
  const bool tagged = layout.time == InsTimeSource::Tag;
  const double tag = tagged ? ins_tag(Role::InsVelEastTimeTag, s.t_s) : 0;
  // a garbled velocity: no INS on a still table moves at 2000 m/s
  std::bernoulli_distribution spike(std::clamp(setup_.faults.ins_spike_rate, 0.0, 1.0));
  const double ve = setup_.faults.ins_spike_rate > 0 && spike(rng_) ? 2000.0 : s.ve;
  // in the DBC's unit and the layout's sign
  const double east =
      ve * layout.east_sign / velocity_unit(*roles_[Role::InsVelEast].signal).value();
  const double north =
      s.vn * layout.north_sign / velocity_unit(*roles_[Role::InsVelNorth].signal).value();
  std::bernoulli_distribution drop(std::clamp(setup_.faults.ins_drop_rate, 0.0, 1.0));
  auto dropped = [&] {
    if (!ins_quiet(s.t_s) && !(setup_.faults.ins_drop_rate > 0 && drop(rng_))) return false;
    ++counts_.dropped;
    return true;
  };
  if (layout.time == InsTimeSource::TimeFrame && !ins_quiet(s.t_s)) {
    // the device time frame goes just before the velocity it stamps
    const std::pair<Role, double> time[] = {{Role::InsTime, ins_tag(Role::InsTime, s.t_s)}};
    out.push_back({s.t_s, true, encode(Role::InsTime, time)});
  }
  if (roles_[Role::InsVelEast].message == roles_[Role::InsVelNorth].message) {
    const std::pair<Role, double> both[] = {
        {Role::InsVelEast, east}, {Role::InsVelNorth, north}, {Role::InsVelEastTimeTag, tag}};
    if (!dropped()) out.push_back({s.t_s, true, encode(Role::InsVelEast, both)});
    return;
  }
  const double north_tag = tagged ? ins_tag(Role::InsVelNorthTimeTag, s.t_s) : 0;
  const std::pair<Role, double> e[] = {{Role::InsVelEast, east}, {Role::InsVelEastTimeTag, tag}};
  const std::pair<Role, double> n[] = {{Role::InsVelNorth, north},
                                       {Role::InsVelNorthTimeTag, north_tag}};
  for (const auto& vals :
       {std::span<const std::pair<Role, double>>(e), std::span<const std::pair<Role, double>>(n)})
    if (!dropped()) out.push_back({s.t_s, true, encode(vals[0].first, vals)});
}

void VirtualStand::emit_encoder(double t, std::vector<StandFrame>& out) {
  if (t >= setup_.faults.encoder_silent_at_s) {
    ++counts_.dropped;
    return;
  }
  // u32 of a revolution, wrapping: the physical value from the wrapped raw
  // count, so the codec reproduces it exactly
  const double rev = table_.angle(t) / kTwoPi;
  const double frac = rev - std::floor(rev);
  double raw = std::round(frac * 4294967296.0);
  if (raw >= 4294967296.0) raw = 0;
  const std::pair<Role, double> v[] = {
      {Role::EncoderAngle, raw * (360.0 / 4294967296.0)},
      {Role::EncoderTimeTag, static_cast<double>(setup_.table_clock.tag(t))}};
  out.push_back({t, false, encode(Role::EncoderAngle, v)});
}

void VirtualStand::emit_table_status(double t, std::vector<StandFrame>& out) {
  const TableStatus s = table_.status(t);
  const std::pair<Role, double> v[] = {{Role::TableState, static_cast<double>(s.state)},
                                       {Role::TableAck, static_cast<double>(s.ack_seq)},
                                       {Role::TableFault, static_cast<double>(s.fault)},
                                       {Role::TableRate, s.rate_rps / kDeg}};
  out.push_back({t, false, encode(Role::TableState, v)});
}

void VirtualStand::emit_garbage(double t, std::vector<StandFrame>& out) {
  can::Frame f;
  if (garbage_k_ % 2 == 0) {
    f = encode(Role::InsVelEast, {});  // a known ID with a wrong length
    f.len = 3;
  } else {
    f.id = unknown_id(codec_);
    f.len = 8;
  }
  out.push_back({t, true, f});
}

void VirtualStand::note_turn(double t) {
  StandFaults& f = setup_.faults;
  // nothing timed from the turn (most runs): no motion looked up each step
  if (turned_ ||
      (std::isnan(f.ins_silent_after_turn_s) && std::isnan(f.encoder_silent_after_turn_s)))
    return;
  const TableMotion& m = drive_ ? drive_->motion() : table_.motion();
  if (m.at(t).rate == 0) return;
  turned_ = true;
  // NaN stays NaN: std::fmin takes the number
  f.ins_silent_at_s = std::fmin(f.ins_silent_at_s, t + f.ins_silent_after_turn_s);
  f.encoder_silent_at_s = std::fmin(f.encoder_silent_at_s, t + f.encoder_silent_after_turn_s);
}

void VirtualStand::advance(double t, std::vector<StandFrame>& out) {
  const StandFaults& f = setup_.faults;
  const double inf = std::numeric_limits<double>::infinity();
  const std::size_t first = out.size();
  // the drive's answers to the host's frames since the last advance
  auto flush_drive = [&] {
    for (const DriveFrame& d : drive_out_) out.push_back({d.t_s, false, d.frame});
    drive_out_.clear();
  };
  if (drive_) flush_drive();
  auto flush_velocity = [&](double upto) {
    ins_.advance(upto, vel_);
    for (InsVelocity& v : vel_) {
      v.t_s = std::min(v.t_s, upto);  // round-off of t0 + k dt: keep the order
      emit_velocity(v, out);
    }
    vel_.clear();
  };
  for (;;) {
    const double ts = static_cast<double>(ins_status_k_) / setup_.ins_status_hz;
    const double te = static_cast<double>(encoder_k_) / setup_.encoder_hz;
    // a CiA 402 drive sends its own frames (TPDOs, heartbeat, EMCY): the
    // encoder's rate steps it, the reference table's status is not sent
    const double tt = drive_ ? inf : static_cast<double>(table_status_k_) / setup_.table_status_hz;
    const double tg =
        f.garbage_rate_hz > 0 ? static_cast<double>(garbage_k_ + 1) / f.garbage_rate_hz : inf;
    const double tf = f.flood_s > 0 && f.flood_rate_hz > 0
                          ? f.flood_at_s + static_cast<double>(flood_k_) / f.flood_rate_hz
                          : inf;
    const bool flood_on = tf < f.flood_at_s + f.flood_s;
    const double tn = std::min({ts, te, tt, tg, flood_on ? tf : inf});
    if (tn > t) break;
    table_.advance(tn);
    note_turn(tn);
    flush_velocity(tn);
    if (ts == tn) {
      emit_ins_status(tn, out);
      ++ins_status_k_;
    }
    if (te == tn) {
      if (drive_) {
        drive_->advance(tn, drive_out_);
        flush_drive();
      } else {
        emit_encoder(tn, out);
      }
      ++encoder_k_;
    }
    if (tt == tn) {
      emit_table_status(tn, out);
      ++table_status_k_;
    }
    if (tg == tn) {
      emit_garbage(tn, out);
      ++garbage_k_;
    }
    if (flood_on && tf == tn) {
      can::Frame fl;
      fl.id = unknown_id(codec_);
      fl.len = 8;
      out.push_back({tn, true, fl});
      ++flood_k_;
    }
  }
  table_.advance(t);
  if (drive_) {
    drive_->advance(t, drive_out_);
    flush_drive();
  }
  flush_velocity(t);
  now_ = std::max(now_, t);
  // the drive's frames come at their own times: in time order with the INS's
  if (drive_)
    std::stable_sort(out.begin() + static_cast<std::ptrdiff_t>(first), out.end(),
                     [](const StandFrame& a, const StandFrame& b) { return a.t_s < b.t_s; });
}

void VirtualStand::receive(double t, const can::Frame& frame) {
  ++counts_.host_frames;
  table_.advance(t);
  if (drive_) {
    // every host frame reaches the drive: it takes its node's (NMT, SYNC,
    // SDO, RPDO, the host heartbeat) and leaves the others
    drive_->advance(t, drive_out_);
    drive_->receive(t, frame, drive_out_);
    if (codec_.message_for(frame) == nullptr) return;  // CANopen's, no DBC message
  }
  const can::Message* msg = nullptr;
  scratch_.resize(16);
  const can::Message* known = codec_.message_for(frame);
  if (known != nullptr && scratch_.size() < known->signals.size())
    scratch_.resize(known->signals.size());
  if (codec_.decode(frame, scratch_, &msg) != can::DecodeStatus::Ok) {
    ++counts_.host_undecodable;
    return;
  }
  const std::span<const double> v(scratch_.data(), msg->signals.size());
  auto u8 = [](double x) { return static_cast<std::uint8_t>(std::clamp(x, 0.0, 255.0)); };
  if (msg == roles_[Role::TableCommand].message) {
    ++counts_.table_commands;
    const TableCommand c{static_cast<TableCommandCode>(u8(role_value(Role::TableCommand, v))),
                         u8(role_value(Role::TableCommandSeq, v)),
                         role_value(Role::TableCommandTarget, v) * kDeg,
                         role_value(Role::TableCommandRateLimit, v) * kDeg};
    if (c.code == TableCommandCode::QuickStop) ++counts_.quick_stops;
    if (!table_.command(t, c)) ++counts_.refused;
  } else if (msg == roles_[Role::InsCommand].message) {
    ++counts_.ins_commands;
    const InsCommand c{static_cast<InsCommandCode>(u8(role_value(Role::InsCommand, v))),
                       role_value(Role::InsCommandAlignDuration, v),
                       role_value(Role::InsCommandHeading, v) * kDeg,
                       u8(role_value(Role::InsCommandSeq, v))};
    if (!ins_.command(t, c)) ++counts_.refused;
  } else if (msg == roles_[Role::HeartbeatCounter].message) {
    ++counts_.heartbeats;
    table_.heartbeat(t);
  }
}

}  // namespace turncal::stand
