#include "turncal/drivers/cia402.hpp"

#include "cia402_detail.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cstdio>
#include <limits>
#include <utility>

namespace turncal::cia402 {

using canopen::get_le;
using canopen::le_bytes;
using canopen::put_le;

namespace {

using detail::hex;
using detail::kRadToDeg;
using detail::num;
using detail::to_u32_counts;

/// How often 0x6061 is read while the drive switches its mode.
constexpr double kModePollPeriod_s = 0.005;

Status field_in(const PdoField& f, std::uint8_t size, std::uint8_t length, const char* what) {
  if (!f.present()) return make_error(std::string("PDO layout: no ") + what);
  if (f.length != length)
    return make_error(std::string("PDO layout: ") + what + " of " + std::to_string(f.length) +
                      " bytes (" + std::to_string(length) + " expected)");
  if (f.offset + f.length > size)
    return make_error(std::string("PDO layout: ") + what + " at byte " + std::to_string(f.offset) +
                      " runs past the payload of " + std::to_string(size) + " bytes");
  return Ok{};
}

bool overlap(const PdoField& a, const PdoField& b) {
  return a.present() && b.present() && a.offset < b.offset + b.length &&
         b.offset < a.offset + a.length;
}

Result<PdoField> field_from_signal(const can::Message& msg, std::string_view name,
                                   std::uint32_t bits) {
  const can::Signal* s = msg.find_signal(name);
  if (s == nullptr)
    return make_error("DBC message " + msg.name + " has no signal " + std::string(name));
  const std::string who = msg.name + "." + s->name;
  if (s->order != can::ByteOrder::LittleEndian)
    return make_error(who + ": a PDO carries its objects little-endian (@1)");
  if (s->start_bit % 8 != 0) return make_error(who + ": not byte aligned");
  if (s->length != bits)
    return make_error(who + ": " + std::to_string(s->length) + " bits, the object has " +
                      std::to_string(bits));
  if (s->type != can::ValueType::Integer || s->factor != 1 || s->offset != 0 ||
      s->mux != can::MuxRole::None)
    return make_error(who + ": must be the object's raw integer (factor 1, offset 0)");
  return PdoField{static_cast<std::uint8_t>(s->start_bit / 8), static_cast<std::uint8_t>(bits / 8)};
}

Status message_fits(const can::Message& msg) {
  if (msg.extended || msg.id > 0x7FF)
    return make_error("DBC message " + msg.name + ": a PDO has an 11-bit identifier");
  if (msg.size > 8) return make_error("DBC message " + msg.name + ": a PDO has at most 8 bytes");
  return Ok{};
}

struct MapEntry {
  PdoField field;
  std::uint16_t index;
};

Result<std::vector<std::uint32_t>> mapping_of(std::vector<MapEntry> entries, std::uint8_t size) {
  std::sort(entries.begin(), entries.end(),
            [](const MapEntry& a, const MapEntry& b) { return a.field.offset < b.field.offset; });
  std::vector<std::uint32_t> out;
  std::uint32_t at = 0;
  for (const MapEntry& e : entries) {
    if (e.field.offset != at)
      return make_error("PDO layout: a gap at byte " + std::to_string(at) +
                        " cannot be written as a mapping");
    out.push_back(static_cast<std::uint32_t>(e.index) << 16 | (8u * e.field.length));
    at += e.field.length;
  }
  if (at != size)
    return make_error("PDO layout: the objects fill " + std::to_string(at) + " of " +
                      std::to_string(size) + " bytes");
  return out;
}

}  // namespace

const char* object_name(std::uint16_t index) {
  switch (index) {
    case obj::kAbortConnectionOption:
      return "abort connection option code";
    case obj::kErrorCode:
      return "error code";
    case obj::kControlword:
      return "controlword";
    case obj::kStatusword:
      return "statusword";
    case obj::kQuickStopOption:
      return "quick stop option code";
    case obj::kShutdownOption:
      return "shutdown option code";
    case obj::kDisableOperationOption:
      return "disable operation option code";
    case obj::kModesOfOperation:
      return "modes of operation";
    case obj::kModesDisplay:
      return "modes of operation display";
    case obj::kPositionActual:
      return "position actual value";
    case obj::kVelocityActual:
      return "velocity actual value";
    case obj::kTargetPosition:
      return "target position";
    case obj::kMaxProfileVelocity:
      return "max profile velocity";
    case obj::kProfileVelocity:
      return "profile velocity";
    case obj::kProfileAcceleration:
      return "profile acceleration";
    case obj::kProfileDeceleration:
      return "profile deceleration";
    case obj::kQuickStopDeceleration:
      return "quick stop deceleration";
    case obj::kDeviceName:
      return "manufacturer device name";
    case obj::kConsumerHeartbeat:
      return "consumer heartbeat time";
    case obj::kProducerHeartbeat:
      return "producer heartbeat time";
    case obj::kRpdo1Comm:
      return "RPDO1 communication parameter";
    case obj::kRpdo1Map:
      return "RPDO1 mapping";
    case obj::kTpdo1Comm:
      return "TPDO1 communication parameter";
    case obj::kTpdo1Map:
      return "TPDO1 mapping";
    case obj::kTpdo2Comm:
      return "TPDO2 communication parameter";
    case obj::kTpdo2Map:
      return "TPDO2 mapping";
    default:
      return nullptr;
  }
}

const char* to_string(State s) {
  switch (s) {
    case State::NotReadyToSwitchOn:
      return "not ready to switch on";
    case State::SwitchOnDisabled:
      return "switch on disabled";
    case State::ReadyToSwitchOn:
      return "ready to switch on";
    case State::SwitchedOn:
      return "switched on";
    case State::OperationEnabled:
      return "operation enabled";
    case State::QuickStopActive:
      return "quick stop active";
    case State::FaultReactionActive:
      return "fault reaction active";
    case State::Fault:
      return "fault";
    case State::Unknown:
      break;
  }
  return "unknown";
}

// CiA 402, statusword coding of the states: masks 0x4F and 0x6F.
State decode_state(std::uint16_t s) {
  struct Row {
    std::uint16_t mask, value;
    State state;
  };
  static constexpr std::array<Row, 8> kTable{{
      {0x4F, 0x00, State::NotReadyToSwitchOn},
      {0x4F, 0x40, State::SwitchOnDisabled},
      {0x6F, 0x21, State::ReadyToSwitchOn},
      {0x6F, 0x23, State::SwitchedOn},
      {0x6F, 0x27, State::OperationEnabled},
      {0x6F, 0x07, State::QuickStopActive},
      {0x4F, 0x0F, State::FaultReactionActive},
      {0x4F, 0x08, State::Fault},
  }};
  for (const Row& r : kTable)
    if ((s & r.mask) == r.value) return r.state;
  return State::Unknown;
}

std::uint16_t state_bits(State s) {
  switch (s) {
    case State::NotReadyToSwitchOn:
      return 0x00;
    case State::SwitchOnDisabled:
      return 0x40;
    case State::ReadyToSwitchOn:
      return 0x21;
    case State::SwitchedOn:
      return 0x23;
    case State::OperationEnabled:
      return 0x27;
    case State::QuickStopActive:
      return 0x07;
    case State::FaultReactionActive:
      return 0x0F;
    case State::Fault:
      return 0x08;
    case State::Unknown:
      break;
  }
  return 0x00;
}

const char* to_string(Command c) {
  switch (c) {
    case Command::Shutdown:
      return "shutdown";
    case Command::SwitchOn:
      return "switch on";
    case Command::EnableOperation:
      return "enable operation";
    case Command::DisableVoltage:
      return "disable voltage";
    case Command::QuickStop:
      return "quick stop";
    case Command::FaultReset:
      return "fault reset";
    case Command::None:
      break;
  }
  return "none";
}

// CiA 402, command coding (bits 7, 3, 2, 1, 0):
//   shutdown          0 x 1 1 0      switch on         0 0 1 1 1
//   disable voltage   0 x x 0 x      quick stop        0 x 0 1 x
//   enable operation  0 1 1 1 1      fault reset       0->1 x x x x
Command decode_command(std::uint16_t c, std::uint16_t previous) {
  if ((c & cw::kFaultReset) != 0)
    return (previous & cw::kFaultReset) == 0 ? Command::FaultReset : Command::None;
  if ((c & cw::kEnableVoltage) == 0) return Command::DisableVoltage;
  if ((c & cw::kQuickStop) == 0) return Command::QuickStop;
  if ((c & cw::kSwitchOn) == 0) return Command::Shutdown;
  return (c & cw::kEnableOperation) != 0 ? Command::EnableOperation : Command::SwitchOn;
}

// ---- layouts ----

RpdoLayout RpdoLayout::defaults(std::uint8_t node) {
  RpdoLayout l;
  l.cob_id = canopen::kRpdo1Base + node;
  return l;
}

Result<RpdoLayout> RpdoLayout::from_dbc(const can::Message& msg, std::string_view controlword,
                                        std::string_view target_position) {
  TURNCAL_TRY(message_fits(msg));
  RpdoLayout l;
  l.cob_id = msg.id;
  l.size = static_cast<std::uint8_t>(msg.size);
  TURNCAL_ASSIGN(c, field_from_signal(msg, controlword, 16));
  TURNCAL_ASSIGN(t, field_from_signal(msg, target_position, 32));
  l.controlword = c;
  l.target_position = t;
  TURNCAL_TRY(l.check());
  return l;
}

Status RpdoLayout::check() const {
  if (cob_id == 0 || cob_id > 0x7FF) return make_error("RPDO layout: COB-ID " + hex(cob_id, 3));
  if (size > 8) return make_error("RPDO layout: more than 8 bytes");
  TURNCAL_TRY(field_in(controlword, size, 2, "controlword"));
  TURNCAL_TRY(field_in(target_position, size, 4, "target position"));
  if (overlap(controlword, target_position))
    return make_error("RPDO layout: controlword and target position overlap");
  return Ok{};
}

Result<std::vector<std::uint32_t>> RpdoLayout::mapping() const {
  TURNCAL_TRY(check());
  return mapping_of({{controlword, obj::kControlword}, {target_position, obj::kTargetPosition}},
                    size);
}

TpdoLayout TpdoLayout::defaults(std::uint8_t node) {
  TpdoLayout l;
  l.cob_id = canopen::kTpdo1Base + node;
  return l;
}

Result<TpdoLayout> TpdoLayout::from_dbc(const can::Message& msg, std::string_view statusword,
                                        std::string_view position_actual) {
  TURNCAL_TRY(message_fits(msg));
  TpdoLayout l;
  l.cob_id = msg.id;
  l.size = static_cast<std::uint8_t>(msg.size);
  TURNCAL_ASSIGN(s, field_from_signal(msg, statusword, 16));
  TURNCAL_ASSIGN(p, field_from_signal(msg, position_actual, 32));
  l.statusword = s;
  l.position_actual = p;
  TURNCAL_TRY(l.check());
  return l;
}

Status TpdoLayout::check() const {
  if (cob_id == 0 || cob_id > 0x7FF) return make_error("TPDO layout: COB-ID " + hex(cob_id, 3));
  if (size > 8) return make_error("TPDO layout: more than 8 bytes");
  TURNCAL_TRY(field_in(statusword, size, 2, "statusword"));
  TURNCAL_TRY(field_in(position_actual, size, 4, "position actual"));
  if (overlap(statusword, position_actual))
    return make_error("TPDO layout: statusword and position actual overlap");
  return Ok{};
}

Result<std::vector<std::uint32_t>> TpdoLayout::mapping() const {
  TURNCAL_TRY(check());
  return mapping_of({{statusword, obj::kStatusword}, {position_actual, obj::kPositionActual}},
                    size);
}

VelocityPdoLayout VelocityPdoLayout::defaults(std::uint8_t node) {
  VelocityPdoLayout l;
  l.cob_id = canopen::kTpdo2Base + node;
  return l;
}

Result<VelocityPdoLayout> VelocityPdoLayout::from_dbc(const can::Message& msg,
                                                      std::string_view velocity_actual) {
  TURNCAL_TRY(message_fits(msg));
  VelocityPdoLayout l;
  l.cob_id = msg.id;
  l.size = static_cast<std::uint8_t>(msg.size);
  TURNCAL_ASSIGN(v, field_from_signal(msg, velocity_actual, 32));
  l.velocity_actual = v;
  TURNCAL_TRY(l.check());
  return l;
}

Status VelocityPdoLayout::check() const {
  if (cob_id == 0 || cob_id > 0x7FF) return make_error("TPDO2 layout: COB-ID " + hex(cob_id, 3));
  if (size > 8) return make_error("TPDO2 layout: more than 8 bytes");
  return field_in(velocity_actual, size, 4, "velocity actual");
}

Result<std::vector<std::uint32_t>> VelocityPdoLayout::mapping() const {
  TURNCAL_TRY(check());
  return mapping_of({{velocity_actual, obj::kVelocityActual}}, size);
}

// ---- settings ----

Status MasterSettings::check() const {
  if (!canopen::valid_node(node_id))
    return make_error("drive node id " + std::to_string(node_id) + " is not 1..127");
  if (!canopen::valid_node(host_node_id) || host_node_id == node_id)
    return make_error("host node id " + std::to_string(host_node_id) +
                      " is not 1..127 or is the drive's");
  auto positive = [](double v) { return std::isfinite(v) && v > 0; };
  if (!positive(counts_per_rev) || !positive(gear_ratio))
    return make_error("counts per revolution and gear ratio must be positive");
  if (!positive(host_heartbeat_period_s) || !positive(drive_heartbeat_period_s) ||
      !positive(sdo_timeout_s) || !positive(boot_timeout_s))
    return make_error("heartbeat periods and timeouts must be positive");
  if (!(host_heartbeat_timeout_s > host_heartbeat_period_s))
    return make_error("the host heartbeat timeout must exceed its period");
  if (!(drive_heartbeat_timeout_s > drive_heartbeat_period_s))
    return make_error("the drive heartbeat timeout must exceed its period");
  const double host_ms = std::round(host_heartbeat_timeout_s * 1000);
  const double drive_ms = std::round(drive_heartbeat_period_s * 1000);
  // 0 ms would switch the drive's watch of us off (0x1016:01)
  if (host_ms < 1 || host_ms > 65535 || drive_ms < 1 || drive_ms > 65535)
    return make_error("heartbeat times must be 1 to 65535 ms (0x1016, 0x1017)");
  // CiA 402: 0x605A 0..8 defined (9.. reserved, negative the maker's own);
  // 0x6007 0..3 (4.. reserved, negative the maker's own)
  if (quick_stop_option < 0 || quick_stop_option > 8)
    return make_error("quick stop option code " + std::to_string(quick_stop_option) +
                      " is not one CiA 402 defines (0 to 8, 0x605A)");
  if (abort_connection_option < 0 || abort_connection_option > 3)
    return make_error("abort connection option code " + std::to_string(abort_connection_option) +
                      " is not one CiA 402 defines (0 to 3, 0x6007)");
  // and of those, none that lets the table coast or run on: a quick stop
  // that disables the drive (0x605A = 0), a lost host that is ignored or
  // switches the voltage off (0x6007 = 0, 2); the configuration's keys
  // refuse them with their line, this holds for every other way in
  if (quick_stop_option == 0)
    return make_error(
        "quick stop option code 0 (disable drive function, 0x605A) lets the table "
        "coast on a quick stop");
  if (abort_connection_option == 0 || abort_connection_option == 2)
    return make_error("abort connection option code " + std::to_string(abort_connection_option) +
                      (abort_connection_option == 0 ? " (no action" : " (disable voltage") +
                      ", 0x6007) does not stop the table when the drive loses the host");
  if (!positive(set_point_timeout_s) || !positive(fault_reset_low_s) ||
      !positive(mode_switch_timeout_s))
    return make_error("set-point, fault reset and mode switch times must be positive");
  if (!(sync_period_s >= 0) || !std::isfinite(sync_period_s))
    return make_error("SYNC period must be 0 (none) or positive");
  const double cpr = counts_per_rad();
  const double per_deg = cpr / kRadToDeg;
  TURNCAL_TRY(to_u32_counts(profile_velocity_rps * kRadToDeg, per_deg, "profile velocity",
                            obj::kProfileVelocity, "deg/s"));
  TURNCAL_TRY(to_u32_counts(profile_acceleration_rps2 * kRadToDeg, per_deg, "profile acceleration",
                            obj::kProfileAcceleration, "deg/s^2"));
  TURNCAL_TRY(to_u32_counts(profile_deceleration_rps2 * kRadToDeg, per_deg, "profile deceleration",
                            obj::kProfileDeceleration, "deg/s^2"));
  TURNCAL_TRY(to_u32_counts(quick_stop_deceleration_rps2 * kRadToDeg, per_deg,
                            "quick stop deceleration", obj::kQuickStopDeceleration, "deg/s^2"));
  TURNCAL_TRY(rpdo_layout().check());
  TURNCAL_TRY(tpdo_layout().check());
  if (velocity_pdo) {
    TURNCAL_TRY(velocity_layout().check());
    if (configure_mapping) TURNCAL_TRY(velocity_layout().mapping());
  }
  {
    // every PDO's identifier is its own: not another PDO's, nor one of the
    // predefined connection set's this bus uses (CiA 301, 7.3.5)
    struct Id {
      std::uint32_t id;
      const char* what;
    };
    const Id fixed[] = {{canopen::kNmtId, "NMT"},
                        {canopen::kSyncId, "SYNC"},
                        {canopen::kEmcyBase + node_id, "the drive's EMCY"},
                        {canopen::kSdoTxBase + node_id, "the drive's SDO response"},
                        {canopen::kSdoRxBase + node_id, "the drive's SDO request"},
                        {canopen::kHeartbeatBase + node_id, "the drive's heartbeat"},
                        {canopen::kHeartbeatBase + host_node_id, "our heartbeat"}};
    std::vector<Id> pdos{{rpdo_layout().cob_id, "RPDO1"}, {tpdo_layout().cob_id, "TPDO1"}};
    if (velocity_pdo) pdos.push_back({velocity_layout().cob_id, "TPDO2"});
    for (std::size_t i = 0; i < pdos.size(); ++i) {
      for (std::size_t j = i + 1; j < pdos.size(); ++j)
        if (pdos[i].id == pdos[j].id)
          return make_error(std::string(pdos[j].what) + "'s COB-ID " + hex(pdos[j].id, 3) + " is " +
                            pdos[i].what + "'s");
      for (const Id& f : fixed)
        if (pdos[i].id == f.id)
          return make_error(std::string(pdos[i].what) + "'s COB-ID " + hex(pdos[i].id, 3) + " is " +
                            f.what + "'s");
    }
  }
  if (configure_mapping) {
    TURNCAL_TRY(rpdo_layout().mapping());
    TURNCAL_TRY(tpdo_layout().mapping());
    const double ms = std::round(tpdo_event_timer_s * 1000);
    if (sync_period_s == 0 && !(ms >= 1 && ms <= 65535))
      return make_error("TPDO event timer must be 1 to 65535 ms (0x1800:05)");
  }
  // TPDO1's positions are the table's rate and its rest: a period over
  // half the drive's heartbeat timeout leaves them unknown between two
  // (the drive's own transmission, when the mapping is not written, is
  // read back from it: check_tpdo)
  if (const double period = sync_period_s > 0 ? sync_period_s : tpdo_event_timer_s;
      (sync_period_s > 0 || configure_mapping) &&
      !tpdo_period_fits(period, drive_heartbeat_timeout_s))
    return make_error("TPDO1's period (" + num(period * 1000) + " ms, " +
                      (sync_period_s > 0 ? "the SYNC period" : "its event timer") +
                      ") must be positive and at most half the drive heartbeat timeout (" +
                      num(drive_heartbeat_timeout_s * 1000) +
                      " ms): the table's rate and rest come from its positions");
  // a resolution so coarse that the dither allowance needs more than a
  // second to read as rest: the rate and the rest would lag a stop by
  // seconds, past the sequencer's limits
  if (const double per_turn = counts_per_rev * gear_ratio; per_turn < kMinCountsPerTableTurn)
    return make_error("the table's resolution, " + num(per_turn) +
                      " counts per table turn (counts per revolution x gear ratio), is under " +
                      num(kMinCountsPerTableTurn) + ": a rest of " +
                      num(kTableAtRestRps * kRadToDeg) +
                      " deg/s would take over a second to tell from a count of dither");
  return Ok{};
}

const char* to_string(CommPhase p) {
  switch (p) {
    case CommPhase::Idle:
      return "idle";
    case CommPhase::WaitBootUp:
      return "waiting for boot-up";
    case CommPhase::Configuring:
      return "configuring";
    case CommPhase::Running:
      return "running";
    case CommPhase::Failed:
      return "configuration failed";
  }
  return "unknown";
}

// ---- the master ----

Master::Master(MasterSettings s) : Master(std::move(s), make_profile_position) {}

Master::Master(MasterSettings s, const ModeFactory& mode)
    : s_(std::move(s)),
      rpdo_(s_.rpdo_layout()),
      tpdo_(s_.tpdo_layout()),
      tpdo2_(s_.velocity_layout()),
      cpr_(s_.counts_per_rad()),
      sdo_(s_.node_id, s_.sdo_timeout_s),
      mode_(mode(s_, *this)) {
  if (const Status ok = s_.check(); !ok) invalid_ = ok.error().message;
}

Result<std::unique_ptr<Master>> Master::create(MasterSettings s) {
  TURNCAL_TRY(s.check());
  return std::make_unique<Master>(std::move(s));
}

void Master::start(double now_s, std::vector<can::Frame>& out) {
  now_ = now_s;
  if (!invalid_.empty()) {  // nothing goes to the drive
    phase_ = CommPhase::Failed;
    latch(FaultCode::Configuration, "invalid settings: " + invalid_);
    return;
  }
  host_hb_on_ = true;
  next_host_hb_ = now_s;
  next_sync_ = now_s;
  reset_comm(now_s, out);
  tick(now_s, out);
}

Master::Rest Master::rest_since_running() const {
  // over a window of TPDO1s since the NMT start, not two samples (over()).
  // Not known: no window yet, or no position for the drive's heartbeat
  // timeout.
  if (tpdo_running_ == 0 || now_ - last_tpdo_t_ > s_.drive_heartbeat_timeout_s) return {};
  return over(rest_win_);
}

Master::Rest Master::over(const PosWindow& w) const {
  // the latest position against the window's base: a table that has since
  // stopped is judged by now, not by its past. A count or two of dither
  // over it is rest (rate 0); turning: more than that, and over
  // kTableAtRestRps.
  Rest r;
  const double dt = last_sample_t_ - w.base.t;
  if (!(dt >= rate_window_s())) return r;  // NaN: no window yet
  const auto dc = static_cast<double>(pos_counts_ - w.base.counts);
  r.rate_rps = std::abs(dc) <= kRestDitherCounts ? 0.0 : sense() * dc / cpr_ / dt;
  r.state = std::abs(r.rate_rps) > kTableAtRestRps ? Rest::Turning : Rest::AtRest;
  return r;
}

double Master::rate_window_s() const {
  // kRestDitherCounts over the window read at most 80% of the rest rate
  return std::max(kRestWindowS, 1.25 * kRestDitherCounts / cpr_ / kTableAtRestRps);
}

void Master::add_position(PosWindow& w, double t, std::int64_t counts) const {
  // the first position, or the first after the drive's heartbeat timeout
  // without one: the window starts here
  if (std::isnan(w.last_t) || t - w.last_t > s_.drive_heartbeat_timeout_s) {
    w.base = w.next = {t, counts};
  } else if (t - w.next.t >= rate_window_s()) {
    w.base = w.next;
    w.next = {t, counts};
  }
  w.last_t = t;
}

double Master::start_up_budget_s() const {
  // configure() writes 11 objects and the mode's besides the PDOs, each of
  // three PDOs at most 6 and its entries (8 of a byte or more in 8 bytes),
  // then reads the mode's objects back and 0x6061: some 60 transfers, each
  // bounded by the SDO timeout
  std::vector<ConfigWrite> writes;
  mode_->configuration(writes);
  const double transfers =
      static_cast<double>(11 + writes.size() + 3 * (6 + 8) + mode_->checks().size() + 1);
  return s_.boot_timeout_s + transfers * s_.sdo_timeout_s + s_.mode_switch_timeout_s;
}

void Master::reset_comm(double now_s, std::vector<can::Frame>& out) {
  // the configuration's and a waiting move's transfers end here: their
  // callbacks see a stale generation or no move waiting, and do nothing
  ++config_generation_;
  ++status_read_gen_;    // and a fault reset's read of the statusword: asked
  status_read_.reset();  // again once the drive runs
  if (recovery_ == Recovery::ReadStatus) recovery_ = Recovery::SendReset;
  mode_poll_at_ = INFINITY;  // a poll of the configuration that ends here
  config_complete_ = false;
  mode_->reset();
  // a warning's statusword read ends here too (its callback a stale
  // generation): read again once the drive runs
  ++warning_gen_;
  if (warning_in_flight_) warning_read_at_ = std::min(warning_read_at_, now_s);
  warning_in_flight_ = false;
  warning_again_ = false;
  sdo_.cancel_all(out);
  out.push_back(canopen::nmt_frame(canopen::NmtCommand::ResetCommunication, s_.node_id));
  ++counts_.nmt_resets;
  // an automatic retry (no boot-up) goes on the same start-up and its bound
  if (phase_ != CommPhase::WaitBootUp) starting_since_ = now_s;
  phase_ = CommPhase::WaitBootUp;
  boot_deadline_ = now_s + s_.boot_timeout_s;
  drive_seen_operational_ = false;
  drive_hb_lost_ = false;
  configured_mapping_ = false;
  sw_.reset();
  state_ = State::Unknown;
  cw_sent_ = false;
}

void Master::configure(double now_s, std::vector<can::Frame>& out) {
  phase_ = CommPhase::Configuring;
  const std::uint64_t gen = ++config_generation_;
  using Step = ConfigWrite;
  const double per_deg = cpr_ / kRadToDeg;
  auto u32 = [&](double v_rad, const char* what, std::uint16_t index) {
    // the constructor's check() has proved these fit (start() and
    // command() go no further when it failed)
    return to_u32_counts(v_rad * kRadToDeg, per_deg, what, index, "deg").value();
  };
  std::vector<Step> steps;
  steps.push_back(
      {obj::kModesOfOperation, 0, le_bytes(static_cast<std::uint8_t>(mode_->code()), 1)});
  mode_->configuration(steps);  // the mode's own objects
  steps.push_back({obj::kProfileAcceleration, 0,
                   le_bytes(u32(s_.profile_acceleration_rps2, "a", obj::kProfileAcceleration), 4)});
  steps.push_back({obj::kProfileDeceleration, 0,
                   le_bytes(u32(s_.profile_deceleration_rps2, "d", obj::kProfileDeceleration), 4)});
  steps.push_back(
      {obj::kQuickStopDeceleration, 0,
       le_bytes(u32(s_.quick_stop_deceleration_rps2, "q", obj::kQuickStopDeceleration), 4)});
  steps.push_back(
      {obj::kQuickStopOption, 0, le_bytes(static_cast<std::uint16_t>(s_.quick_stop_option), 2)});
  // Shutdown (transition 8) and disable operation (5) slow down on the
  // profile deceleration before the power stage lets go (code 1), where
  // many drives' default, 0, lets a moving table coast. The master sends
  // neither while it knows the table moves; this holds when it does not.
  // Both are optional in CiA 402: a drive without them is configured all
  // the same (counted), since the master never disables a turning table.
  steps.push_back({obj::kShutdownOption, 0, le_bytes(1, 2), true});
  steps.push_back({obj::kDisableOperationOption, 0, le_bytes(1, 2), true});
  steps.push_back({obj::kAbortConnectionOption, 0,
                   le_bytes(static_cast<std::uint16_t>(s_.abort_connection_option), 2)});
  const auto host_ms = static_cast<std::uint32_t>(std::round(s_.host_heartbeat_timeout_s * 1000));
  steps.push_back({obj::kConsumerHeartbeat, 1,
                   le_bytes(static_cast<std::uint32_t>(s_.host_node_id) << 16 | host_ms, 4)});
  const auto drive_ms = static_cast<std::uint32_t>(std::round(s_.drive_heartbeat_period_s * 1000));
  steps.push_back({obj::kProducerHeartbeat, 0, le_bytes(drive_ms, 2)});
  auto pdo = [&](std::uint16_t comm, std::uint16_t map, std::uint32_t cob,
                 const std::vector<std::uint32_t>& entries, bool tpdo) {
    // CiA 301 COB-ID entry: bit 31 PDO not valid, bit 30 (a TPDO's) no RTR
    // allowed: nobody asks our drive for its PDOs by remote frame
    if (tpdo) cob |= 0x40000000u;
    steps.push_back({comm, 1, le_bytes(cob | 0x80000000u, 4)});  // PDO not valid
    steps.push_back({map, 0, le_bytes(0, 1)});
    for (std::size_t i = 0; i < entries.size(); ++i)
      steps.push_back({map, static_cast<std::uint8_t>(i + 1), le_bytes(entries[i], 4)});
    steps.push_back({map, 0, le_bytes(entries.size(), 1)});
    if (tpdo) {
      const bool sync = s_.sync_period_s > 0;
      steps.push_back({comm, 2, le_bytes(sync ? 1 : 0xFF, 1)});
      if (!sync)
        steps.push_back(
            {comm, 5,
             le_bytes(static_cast<std::uint32_t>(std::round(s_.tpdo_event_timer_s * 1000)), 2)});
    } else {
      steps.push_back({comm, 2, le_bytes(0xFF, 1)});
    }
    steps.push_back({comm, 1, le_bytes(cob, 4)});  // valid again
  };
  if (s_.configure_mapping) {
    pdo(obj::kRpdo1Comm, obj::kRpdo1Map, rpdo_.cob_id, rpdo_.mapping().value(), false);
    pdo(obj::kTpdo1Comm, obj::kTpdo1Map, tpdo_.cob_id, tpdo_.mapping().value(), true);
    if (s_.velocity_pdo)
      pdo(obj::kTpdo2Comm, obj::kTpdo2Map, tpdo2_.cob_id, tpdo2_.mapping().value(), true);
  } else if (s_.sync_period_s > 0) {
    steps.push_back({obj::kTpdo1Comm, 2, le_bytes(1, 1)});
  }
  const std::size_t n = steps.size();
  for (std::size_t i = 0; i < n; ++i) {
    const bool last = i + 1 == n;
    const bool optional = steps[i].optional;
    sdo_.download(steps[i].index, steps[i].sub, std::move(steps[i].data),
                  [this, gen, last, optional](const canopen::SdoResult& r) {
                    if (gen != config_generation_) return;
                    // the drive's answer that it lacks the object or the value
                    const bool lacks =
                        r.aborted_by_server && (r.abort == 0x06020000u || r.abort == 0x06090011u ||
                                                r.abort == 0x06090030u || r.abort == 0x06090031u);
                    if (!r.ok() && optional && lacks) {
                      ++counts_.ramp_options_refused;
                      const char* name = object_name(r.index);
                      notice(r.describe() +
                             (name != nullptr ? std::string(" [") + name + "]" : "") +
                             ": the drive's own default stands, which may let the table coast on a "
                             "Shutdown or Disable operation (turncal sends neither while the "
                             "table turns)");
                    } else if (!r.ok()) {
                      return config_failed(r, "");
                    }
                    if (last) {
                      mode_->configured();
                      check_tpdo(gen);
                    }
                  });
  }
  sdo_.tick(now_s, out);
}

void Master::read_again(const std::string& why) {
  // up to kConfirmReads; then the reset gives up, and the fault says why
  if (++confirm_reads_ > kConfirmReads) {
    recovery_ = Recovery::None;
    fault_name_ = base_fault_name() + "; " + why;
    return;
  }
  recovery_ = Recovery::SendReset;
}

void Master::notice(std::string text) {
  // told once, however often the drive is configured again
  if (std::find(notices_.begin(), notices_.end(), text) == notices_.end())
    notices_.push_back(std::move(text));
}

void Master::config_failed(const canopen::SdoResult& r, const std::string& why) {
  ++config_generation_;  // the configuration's own callbacks do nothing now
  sdo_.fail_queued();    // a caller's queued transfer hears that it ended
  phase_ = CommPhase::Failed;
  mode_poll_at_ = INFINITY;
  std::string text = why;
  if (text.empty()) {
    const char* name = object_name(r.index);
    text = "SDO abort during configuration: " + r.describe() +
           (name != nullptr ? std::string(" [") + name + "]" : "");
  }
  latch(FaultCode::Configuration, std::move(text), true);
}

void Master::check_tpdo(std::uint64_t gen) {
  // written by the configuration, or sent on our SYNC: known
  if (s_.configure_mapping || s_.sync_period_s > 0)
    return check_options(gen, std::make_shared<std::vector<ConfigCheck>>(mode_->checks()), 0);
  sdo_.upload(obj::kTpdo1Comm, 2, [this, gen](const canopen::SdoResult& r) {
    if (gen != config_generation_) return;
    if (!r.ok()) return config_failed(r, "");
    const std::uint32_t type = r.data.size() == 1 ? r.data[0] : 0xFFFFFFFFu;
    // 254 and 255: event-driven, on the drive's event timer; the others
    // wait on a SYNC we do not send (sync_period_ms = 0) or a remote frame
    if (type != 0xFE && type != 0xFF)
      return config_failed(
          r, "TPDO1's transmission type (0x1800:02) reads " +
                 (r.data.size() == 1 ? std::to_string(type)
                                     : std::to_string(r.data.size()) + " bytes") +
                 ": with no SYNC from turncal (sync_period_ms = 0) the drive would not send it on "
                 "a timer; set it to 254 or 255 with an event timer, set sync_period_ms, or let "
                 "turncal write the mapping (configure_mapping = true)");
    sdo_.upload(obj::kTpdo1Comm, 5, [this, gen](const canopen::SdoResult& t) {
      if (gen != config_generation_) return;
      if (!t.ok()) return config_failed(t, "");
      const double ms = t.data.size() == 2 ? get_le(t.data, 0, 2) : -1.0;
      if (!tpdo_period_fits(ms * 1e-3, s_.drive_heartbeat_timeout_s))
        return config_failed(
            t,
            "TPDO1's event timer (0x1800:05) reads " +
                (t.data.size() == 2 ? num(ms) + " ms" : std::to_string(t.data.size()) + " bytes") +
                (ms == 0 ? " (sent on change only: a table at rest is silent)" : "") +
                ": it must be 1 ms to half the drive heartbeat timeout (" +
                num(s_.drive_heartbeat_timeout_s * 1000) +
                " ms), as the table's rate and rest come from its positions");
      check_options(gen, std::make_shared<std::vector<ConfigCheck>>(mode_->checks()), 0);
    });
  });
}

void Master::check_options(std::uint64_t gen,
                           std::shared_ptr<const std::vector<ConfigCheck>> checks, std::size_t i) {
  if (i == checks->size()) {
    mode_since_ = now_;
    return check_mode(gen);
  }
  const ConfigCheck& c = (*checks)[i];
  sdo_.upload(c.index, c.sub, [this, gen, checks, i](const canopen::SdoResult& r) {
    if (gen != config_generation_) return;
    // CiA 301: 0x06020000 the object, 0x06090011 the sub-index does not exist
    const bool absent = r.aborted_by_server && (r.abort == 0x06020000u || r.abort == 0x06090011u);
    if (!r.ok() && (*checks)[i].optional && absent) {
      const char* name = object_name(r.index);
      notice(r.describe() + (name != nullptr ? std::string(" [") + name + "]" : "") +
             ": optional in CiA 402, not needed; the drive's own behaviour stands");
    } else if (!r.ok()) {
      return config_failed(r, "");
    }
    if (std::string why = (*checks)[i].verdict(r); !why.empty()) return config_failed(r, why);
    check_options(gen, checks, i + 1);
  });
}

void Master::check_mode(std::uint64_t gen) {
  mode_poll_at_ = INFINITY;
  sdo_.upload(obj::kModesDisplay, 0, [this, gen](const canopen::SdoResult& r) {
    if (gen != config_generation_) return;
    if (!r.ok()) return config_failed(r, "");
    const int mode = r.data.size() == 1 ? static_cast<std::int8_t>(r.data[0]) : -1000;
    if (mode == mode_->code()) {
      config_complete_ = true;  // the mode, as written
      return;
    }
    if (r.data.size() != 1)
      return config_failed(r, "modes of operation display (0x6061) reads " +
                                  std::to_string(r.data.size()) + " bytes, not " +
                                  std::to_string(mode_->code()) + " (" + mode_->name() + ")");
    // the drive switches a little later: read again, unless tick() finds
    // the time up (judged there, where a hold of the loop is known first)
    mode_read_ = mode;
    mode_poll_at_ = now_ + kModePollPeriod_s;
  });
}

void Master::config_done(double now_s, std::vector<can::Frame>& out) {
  config_complete_ = false;
  out.push_back(canopen::nmt_frame(canopen::NmtCommand::Start, s_.node_id));
  phase_ = CommPhase::Running;
  started_at_ = now_s;
  next_sync_ = now_s;  // SYNC from the start on, every period (not half one after a stale due)
  tpdo_running_ = 0;
  rest_win_ = {};
  last_drive_hb_ = now_s;
  drive_hb_lost_ = false;
  configured_mapping_ = s_.configure_mapping;
  ++counts_.configurations;
  needs_comm_reset_ = false;  // configured afresh
  cw_sent_ = false;
  if (recovery_ == Recovery::AfterComm) {
    recovery_ = Recovery::SendReset;
    low_t_ = now_s;
  }
}

void Master::abandon_recovery() {
  // a fault reset under way gives way (not a communication reset: that
  // ends in a configuration, which the next Enable needs anyway)
  if (recovery_ == Recovery::AfterComm || recovery_ == Recovery::None) return;
  recovery_ = Recovery::None;
  ++status_read_gen_;  // its statusword read counts no more
}

void Master::latch(FaultCode code, std::string name, bool needs_comm_reset) {
  if (needs_comm_reset) needs_comm_reset_ = true;
  if (fault_ != FaultCode::None) return;  // the first cause stays
  fault_ = code;
  fault_name_ = std::move(name);
  fault_base_ = fault_name_;
  recovery_ = Recovery::None;
}

void Master::tick(double now_s, std::vector<can::Frame>& out) {
  now_ = std::max(now_, now_s);
  if (sends_host_heartbeat() && now_s >= next_host_hb_) {
    out.push_back(canopen::heartbeat_frame(s_.host_node_id, canopen::NmtState::Operational));
    next_host_hb_ += s_.host_heartbeat_period_s;
    if (next_host_hb_ <= now_s) next_host_hb_ = now_s + s_.host_heartbeat_period_s;
  }
  if (s_.sync_period_s > 0 && phase_ == CommPhase::Running && now_s >= next_sync_) {
    out.push_back(canopen::sync_frame());  // its time is its echo's (on_frame)
    // on its schedule, but never two within half a period after a late
    // tick: a drive answers each SYNC within its cycle, and a SYNC on the
    // heels of the last could go out before the last's TPDO1 came back,
    // which would then be dated by the wrong one (and the last read lost)
    next_sync_ = std::max(next_sync_ + s_.sync_period_s, now_s + s_.sync_period_s / 2);
  }
  if (phase_ == CommPhase::WaitBootUp && now_s >= boot_deadline_) {
    latch(FaultCode::NoBootUp,
          "no boot-up from drive node " + std::to_string(s_.node_id) + " within " +
              num(s_.boot_timeout_s) + " s of the NMT reset",
          true);
    reset_comm(now_s, out);  // and try again
  }
  if (phase_ == CommPhase::Configuring && now_s >= mode_poll_at_) {
    if (now_s - mode_since_ >= s_.mode_switch_timeout_s)
      config_failed({}, "modes of operation display (0x6061) reads " + std::to_string(mode_read_) +
                            ", not " + std::to_string(mode_->code()) + " (" + mode_->name() +
                            "), " + num(s_.mode_switch_timeout_s) + " s after 0x6060 was written");
    else
      check_mode(config_generation_);
  }
  read_after_warning(now_s);
  sdo_.tick(now_s, out);
  if (phase_ == CommPhase::Running && !drive_hb_lost_ &&
      now_s - last_drive_hb_ > s_.drive_heartbeat_timeout_s) {
    drive_hb_lost_ = true;
    latch(FaultCode::DriveHeartbeatLost, "drive heartbeat lost", true);
  }
  evaluate(now_s, out, true);
}

void Master::held(double from_s, double to_s) {
  const double length = to_s - from_s;
  if (!(length > 0)) return;
  // what was awaited from `since` on waits as long again as it overlapped
  auto excused = [&](double since) { return std::max(0.0, to_s - std::max(from_s, since)); };
  last_drive_hb_ += excused(last_drive_hb_);
  // a boot-up awaited since before the hold (a reset sent on a frame read
  // after it began its wait after)
  if (phase_ == CommPhase::WaitBootUp && boot_deadline_ - s_.boot_timeout_s <= from_s)
    boot_deadline_ += length;
  mode_->held(from_s, to_s);
  if (phase_ == CommPhase::Configuring) mode_since_ += excused(mode_since_);
  sdo_.held(from_s, to_s);
}

void Master::on_sync(double t_s) {
  // the last SYNC unanswered by the time the next is on the bus: its
  // TPDO1 lost (but not while the drive's stream starts: it sends none in
  // pre-operational)
  if (!std::isnan(sync_.last) && !sync_.answered && !sync_.restarted) ++sync_.missed;
  sync_.last = t_s;
  // a TPDO1 read just before it, received after it, was its answer: the
  // echo read late. An adapter that hands the echo over late may stamp it
  // late too, a little after the answer; a SYNC well after that TPDO1 is
  // a later one (a second answer, or one late, claims no SYNC after it).
  sync_.answered = !std::isnan(sync_.ahead_t) && s_.sync_period_s > 0 &&
                   t_s - sync_.ahead_t <= kEchoLateStamp * s_.sync_period_s &&
                   sync_.ahead_t - t_s <= kSyncAnswerWindow * s_.sync_period_s;
  sync_.ahead_t = NAN;
}

void Master::on_frame(const can::Frame& f, double t_s, std::vector<can::Frame>& out) {
  now_ = std::max(now_, t_s);
  if (f.extended || f.error || f.remote || f.fd) return;
  const std::uint32_t node = s_.node_id;
  if (canopen::on_sync_id(f)) {
    if (!canopen::is_sync(f)) {
      ++counts_.malformed;
      return;
    }
    on_sync(t_s);
    return;
  }
  if (f.id == 0) {
    // NMT to the drive or to all: its TPDOs start over; SYNCs until the
    // first TPDO1 after are no losses (a drive in pre-operational sends
    // none), and a SYNC before the command dates no TPDO1 after it
    if (f.len == 2 && (f.data[1] == node || f.data[1] == 0)) {
      sync_ = SyncPairing{};
    }
    return;
  }
  if (f.id == canopen::kSdoTxBase + node) {
    sdo_.on_frame(f, t_s, out);
  } else if (f.id == canopen::kHeartbeatBase + node) {
    on_heartbeat(f, t_s, out);
  } else if (f.id == canopen::kEmcyBase + node) {
    on_emcy(f, t_s);
  } else if (f.id == tpdo_.cob_id) {
    on_tpdo(f, t_s, out);
  } else if (s_.velocity_pdo && f.id == tpdo2_.cob_id) {
    const auto& v = tpdo2_.velocity_actual;
    if (f.len < v.offset + v.length) {
      ++counts_.malformed;
      return;
    }
    ++counts_.velocity_pdo;
    velocity_ = sense() * static_cast<std::int32_t>(get_le(f.payload(), v.offset, 4)) / cpr_;
    velocity_t_ = t_s;
    return;
  } else {
    return;
  }
  evaluate(t_s, out);
}

void Master::on_heartbeat(const can::Frame& f, double t_s, std::vector<can::Frame>& out) {
  if (f.len != 1) {
    ++counts_.malformed;
    return;
  }
  const auto st = static_cast<canopen::NmtState>(f.data[0]);
  if (st != canopen::NmtState::BootUp && st != canopen::NmtState::Stopped &&
      st != canopen::NmtState::Operational && st != canopen::NmtState::PreOperational) {
    ++counts_.unknown_nmt_states;  // no state CiA 301 defines: counted, skipped
    return;
  }
  ++counts_.heartbeats;
  if (st == canopen::NmtState::BootUp) {
    // a drive that booted may count its position afresh: the unwrap of
    // its s32 starts again from its next position actual
    if (have_pos_) {
      have_pos_ = false;
      last_sample_t_ = NAN;
      rate_ = NAN;
      rate_win_ = rest_win_ = {};
      ++counts_.position_resets;
    }
    if (phase_ == CommPhase::WaitBootUp) {
      out.push_back(canopen::nmt_frame(canopen::NmtCommand::EnterPreOperational, s_.node_id));
      configure(t_s, out);
    } else if (phase_ == CommPhase::Configuring) {
      // its objects are its defaults again: the configuration starts over
      // (a quick stop queued by SDO stays, first)
      latch(FaultCode::DriveNmtState, "drive booted again during its configuration");
      ++config_generation_;  // the queued configuration's callbacks do nothing
      mode_poll_at_ = INFINITY;
      sdo_.fail_queued();
      out.push_back(canopen::nmt_frame(canopen::NmtCommand::EnterPreOperational, s_.node_id));
      configure(t_s, out);
    } else if (phase_ == CommPhase::Running) {
      latch(FaultCode::DriveNmtState, "drive booted again (boot-up while running)", true);
    }
    return;
  }
  last_drive_hb_ = t_s;
  if (phase_ != CommPhase::Running) return;
  if (st == canopen::NmtState::Operational) {
    drive_seen_operational_ = true;
  } else if (drive_seen_operational_ ||
             t_s - started_at_ >
                 std::max(2 * s_.drive_heartbeat_period_s, s_.drive_heartbeat_timeout_s)) {
    // before the drive has said operational, a heartbeat of its state
    // before our NMT start (queued behind the bus, or a drive late to send
    // it) is no news, as long as a heartbeat may be late at all: the
    // consumer timeout (at 2 periods, a stand 20 ms late at 10x failed)
    latch(FaultCode::DriveNmtState,
          std::string("drive NMT state ") + canopen::to_string(st) + " while running", true);
  }
}

void Master::on_emcy(const can::Frame& f, double t_s) {
  auto e = canopen::decode_emcy(f, t_s);
  if (!e) {
    ++counts_.malformed;
    return;
  }
  ++counts_.emcy;
  // a drive that repeats an EMCY without end may not grow us without end:
  // the first ones kept, the last slot always the newest
  if (emcy_.size() < kEmcyKept)
    emcy_.push_back(*e);
  else
    emcy_.back() = *e;
  if (e->code == 0) {       // error reset or no error: no news of a fault
    last_warning_.clear();  // nor of the warnings before it
    return;
  }
  const bool warns = emcy_warns(e->code, s_.emcy_warnings);
  if (fault_ == FaultCode::DriveFault && !warns) {
    // the statusword said fault first; the EMCY says why
    ++emcy_errors_;
    fault_ = FaultCode::Emcy;
    fault_name_ = e->text;
    fault_base_ = fault_name_;
    return;
  }
  if (!warns) {
    ++emcy_errors_;
    latch(FaultCode::Emcy, e->text);
    return;
  }
  // A warning by its code: told, and the drive's statusword decides
  // whether it is more. Its TPDO's fault bit latches the fault (on_tpdo),
  // but a TPDO may be stale (silent or frozen in fault), and a drive may
  // send its EMCY before its statusword shows the fault: the drive's own
  // statusword is read by SDO, at once and again kWarningRecheckS later.
  ++counts_.emcy_warnings;
  last_warning_ = e->text;
  warning_text_ = e->text;
  notice("the drive warned: " + e->text +
         " (a warning by table.cia402.emcy_warnings; the run "
         "goes on unless the drive's statusword shows a fault)");
  warning_reads_left_ = 2;
  // one read at a time (tick); a read under way was sampled before this
  // EMCY, so its answer does not count for it
  if (warning_in_flight_) warning_again_ = true;
  warning_read_at_ = std::min(warning_read_at_, t_s);
}

void Master::read_after_warning(double now_s) {
  // one at a time, in operation: during a reset or the configuration the
  // drive's answer would be no answer (it boots), and the configuration
  // reads its state anyway
  if (warning_read_at_ > now_s || warning_in_flight_ || phase_ != CommPhase::Running) return;
  warning_read_at_ = INFINITY;
  warning_in_flight_ = true;
  const std::uint64_t gen = ++warning_gen_;
  sdo_.upload(obj::kStatusword, 0, [this, gen](const canopen::SdoResult& r) {
    if (gen != warning_gen_) return;
    warning_in_flight_ = false;
    warning_checked(r, warning_text_);
  });
}

void Master::warning_checked(const canopen::SdoResult& r, const std::string& emcy) {
  if (warning_again_) {  // a warning came while this was read: read again, twice
    warning_again_ = false;
    warning_reads_left_ = 2;
    warning_read_at_ = now_;
    return;
  }
  // A fault latched already, or a reset under way: the reset reads the
  // drive itself, and an answer sampled before it is no news
  if (fault_ != FaultCode::None || recovery_ != Recovery::None) {
    warning_reads_left_ = 0;
    return;
  }
  if ((!r.ok() || r.data.size() < 2) && warning_reads_left_ > 1) {
    // one lost or late answer (on a bus that has just reported trouble) is
    // tried once more before it counts
    --warning_reads_left_;
    warning_read_at_ = now_ + kWarningRecheckS;
    return;
  }
  if (!r.ok() || r.data.size() < 2) {
    // not known: taken for a fault, the table stopped (and a reset under
    // way reads the drive again: emcy_errors_)
    ++emcy_errors_;
    warning_reads_left_ = 0;
    latch(FaultCode::Emcy, emcy + "; the drive's statusword could not be read after it (" +
                               (r.ok() ? std::to_string(r.data.size()) + " bytes" : r.describe()) +
                               ")");
    return;
  }
  const auto word = static_cast<std::uint16_t>(get_le(r.data, 0, 2));
  const State s = decode_state(word);
  // the fault bit (or the mode's error bits) decides, and a word that is
  // no state of CiA 402's is no proof of health
  // (the mode's error bits only where on_tpdo judges them)
  const bool judged = s == State::OperationEnabled || s == State::FaultReactionActive ||
                      s == State::Fault || s == State::QuickStopActive;
  if ((word & sw::kFault) != 0 || (judged && (word & mode_->error_bits()) != 0) ||
      s == State::Unknown || s == State::Fault || s == State::FaultReactionActive) {
    ++emcy_errors_;
    warning_reads_left_ = 0;
    latch(FaultCode::Emcy, emcy + " (statusword " + hex(word, 4) + " read after it)");
    return;
  }
  if (--warning_reads_left_ > 0) warning_read_at_ = now_ + kWarningRecheckS;
}

bool emcy_warns(std::uint16_t code,
                const std::vector<std::pair<std::uint16_t, std::uint16_t>>& warnings) {
  return std::any_of(warnings.begin(), warnings.end(),
                     [&](const auto& r) { return code >= r.first && code <= r.second; });
}

void Master::on_tpdo(const can::Frame& f, double t_s, std::vector<can::Frame>& out) {
  (void)out;
  auto end = [](const PdoField& p) { return p.present() ? p.offset + p.length : 0; };
  const int need = std::max(end(tpdo_.statusword), end(tpdo_.position_actual));
  if (f.len < need) {
    ++counts_.malformed;
    return;
  }
  ++counts_.tpdo;
  if (phase_ == CommPhase::Running) ++tpdo_running_;
  const auto p = f.payload();
  const auto word = static_cast<std::uint16_t>(get_le(p, tpdo_.statusword.offset, 2));
  sw_ = word;
  ++sw_seq_;
  const State before = state_;
  state_ = decode_state(word);
  // Out of operation enabled by itself while asked to stay (safe torque
  // off, another node's controlword, the drive's own quick stop): its power
  // stage may be off and the table coasting. Never enabled again behind the
  // operator's back: a fault until the next Enable.
  if (state_ == State::OperationEnabled) last_enabled_seq_ = sw_seq_;
  if (before == State::OperationEnabled && goal_ == Goal::Enabled &&
      other_cw_after_ <= last_enabled_seq_ &&
      (state_ == State::SwitchOnDisabled || state_ == State::ReadyToSwitchOn ||
       state_ == State::SwitchedOn || state_ == State::NotReadyToSwitchOn ||
       state_ == State::QuickStopActive))
    latch(FaultCode::LeftEnabled, std::string("the drive left operation enabled by itself, to ") +
                                      to_string(state_) + " (statusword " + hex(word, 4) + ")");
  const auto raw = static_cast<std::int32_t>(get_le(p, tpdo_.position_actual.offset, 4));
  if (have_pos_) {
    // the drive's s32 wraps; the step between two samples does not
    pos_counts_ += static_cast<std::int32_t>(static_cast<std::uint32_t>(raw) -
                                             static_cast<std::uint32_t>(last_raw_));
  } else {
    pos_counts_ = raw;
  }
  have_pos_ = true;
  last_raw_ = raw;
  angle_ = sense() * static_cast<double>(pos_counts_) / cpr_;
  EncoderSample smp;
  if (s_.sync_period_s <= 0) {
    smp.t_s = t_s;  // no SYNC: its receipt
    smp.lost_before = -1;
  } else if (!std::isnan(sync_.last) && !sync_.answered && t_s >= sync_.last &&
             t_s - sync_.last <= kSyncAnswerWindow * s_.sync_period_s) {
    // the answer to the last SYNC: dated by it; the SYNCs before it that
    // none answered are the losses
    smp.t_s = sync_.last;
    smp.lost_before = sync_.restarted ? EncoderSample::kRestarted : sync_.missed;
    sync_.answered = true;
    sync_.missed = 0;
    sync_.restarted = false;
  } else {
    // no SYNC of its own in sight: none since the last TPDO1 (a second
    // answer to one SYNC, or none since a start), or the last one more
    // than half a period before (no answer comes that late); or its SYNC's
    // echo is read after it. Dated by its receipt; a last SYNC left
    // unanswered is lost, and a SYNC on the bus before it, read after it,
    // is taken as the one it answered (the echo read late), no loss.
    ++counts_.tpdo_unsynced;
    notice(
        "TPDO1s came with no SYNC within half a period before them (a SYNC's echo read after "
        "its answer, an answer late or twice, or no SYNC); each is dated by its receipt");
    smp.t_s = t_s;
    // received before the last SYNC: no answer to it, which stays open for
    // the answer still to come (stamps crossed, or a second answer)
    const bool before_last = !std::isnan(sync_.last) && t_s < sync_.last;
    const bool lost_last = !std::isnan(sync_.last) && !sync_.answered && !before_last;
    // (the SYNCs missed before the last one: said by its answer then)
    smp.lost_before = sync_.restarted ? EncoderSample::kRestarted
                      : before_last   ? 0
                                      : sync_.missed + (lost_last ? 1 : 0);
    if (!before_last) {
      sync_.answered = true;
      sync_.missed = 0;
      sync_.ahead_t = t_s;
    }
    sync_.restarted = false;
  }
  smp.angle_rad = angle_;
  smp.counts = pos_counts_;
  smp.statusword = word;
  const bool later = std::isnan(last_sample_t_) || smp.t_s > last_sample_t_;
  if (later) {
    add_position(rate_win_, smp.t_s, pos_counts_);
    if (phase_ == CommPhase::Running) add_position(rest_win_, smp.t_s, pos_counts_);
  }
  last_sample_t_ = smp.t_s;
  // not the step between two samples: one count of dither between two
  // frames 10 ms apart reads 0.27 deg/s at 2^17 counts per revolution, a
  // turning table to every rest test
  if (later) rate_ = over(rate_win_).rate_rps;
  last_tpdo_t_ = t_s;
  samples_.push_back(smp);
  if ((word & mode_->error_bits()) != 0 &&
      (state_ == State::OperationEnabled || state_ == State::FaultReactionActive ||
       state_ == State::Fault || state_ == State::QuickStopActive))
    latch(FaultCode::FollowingError, std::string(mode_->error_name()) + " (statusword bit " +
                                         std::to_string(std::countr_zero(mode_->error_bits())) +
                                         ")");
  if (state_ == State::Fault || state_ == State::FaultReactionActive)
    latch(FaultCode::DriveFault,
          "drive in fault (statusword " + hex(word, 4) +
              (last_warning_.empty() ? ", no EMCY)"
                                     : ") after " + last_warning_ + ", a code that alone warns"));
}

void Master::send_rpdo(std::uint16_t controlword, std::vector<can::Frame>& out) {
  can::Frame f;
  f.id = rpdo_.cob_id;
  f.len = rpdo_.size;
  put_le(f.data, rpdo_.controlword.offset, 2, controlword);
  put_le(f.data, rpdo_.target_position.offset, 4, static_cast<std::uint32_t>(target_));
  out.push_back(f);
  cw_ = controlword;
  cw_sent_ = true;
  // the drive's answer to another word may come a statusword late (a TPDO
  // sampled before it took the RPDO): only the second one after it counts
  if ((controlword & cw::kCommandMask) != cw::kCmdEnableOperation) other_cw_after_ = sw_seq_ + 2;
}

std::uint16_t Master::motion_bits() const {
  std::uint16_t b = mode_->controlword_bits();
  if (halted_) b |= cw::kHalt;
  return b;
}

void Master::evaluate(double now_s, std::vector<can::Frame>& out, bool timeouts) {
  if (config_complete_) config_done(now_s, out);
  if (phase_ != CommPhase::Running) return;
  const bool fresh_after_ack = sw_ && sw_seq_ > ack_after_;
  // A quick stop is acknowledged whatever else: the drive stopped (quick
  // stop active, or not enabled at all).
  if (ack_on_ == AckOn::Stopped && fresh_after_ack && state_ != State::OperationEnabled &&
      state_ != State::FaultReactionActive && state_ != State::Unknown) {
    ack_ = ack_seq_;
    ack_on_ = AckOn::None;
  }
  if (!recover(now_s, out)) return;
  if (fault_ != FaultCode::None || !sw_) {
    // a latched fault does not stop the drive (many EMCYs are warnings):
    // the quick stop goes on being commanded until the drive shows it
    // after the drive left operation enabled by itself, our enable
    // operation may not stay in its RPDO1 (a drive may take it again)
    if (fault_ != FaultCode::None &&
        (goal_ == Goal::QuickStop || fault_ == FaultCode::LeftEnabled) &&
        (!cw_sent_ || (cw_ & cw::kCommandMask) != cw::kCmdQuickStop))
      send_rpdo(cw::kCmdQuickStop, out);
    return;
  }
  if (!acknowledge(now_s, out, timeouts)) return;
  bool set_point = false;
  const std::optional<std::uint16_t> want = towards_goal(set_point);
  if (!want) return;
  if (set_point) {
    target_ = mode_->set_point_target();
    send_rpdo(*want, out);
    mode_->set_point_sent(sw_seq_, now_s);
  } else if (!cw_sent_ || *want != cw_) {
    send_rpdo(*want, out);
  }
}

bool Master::recover(double now_s, std::vector<can::Frame>& out) {
  const std::uint16_t word = sw_.value_or(0);
  const std::uint16_t faulty = sw::kFault | mode_->error_bits();
  switch (recovery_) {
    case Recovery::AfterComm:
      return false;  // config_done moves it on
    case Recovery::SendReset: {
      // After a reconfiguration the drive's controlword is not known: hear
      // the drive first (its statusword after NMT start is fresh, sw_ was
      // cleared with the reset), for a little while.
      if (!cw_sent_ && !sw_ && now_s - low_t_ < s_.fault_reset_low_s) return false;
      if (now_s < status_read_at_) return false;
      // Whether the drive is in fault, from its own statusword read by SDO:
      // a TPDO may be stale (a drive in fault whose last PDO still says
      // operation enabled), and the fault reset's controlwords, 0x0000 and
      // 0x0080, are Disable voltage to a drive that is not in fault: a
      // moving table would coast.
      const std::uint64_t gen = ++status_read_gen_;
      status_read_.reset();
      recovery_ = Recovery::ReadStatus;
      read_sw_seq_ = sw_seq_;
      read_emcy_ = emcy_errors_;
      sdo_.upload(obj::kStatusword, 0, [this, gen](const canopen::SdoResult& r) {
        if (gen == status_read_gen_ && recovery_ == Recovery::ReadStatus) status_read_ = r;
      });
      return false;
    }
    case Recovery::ReadStatus:
      if (status_read_) on_status_read(now_s, out);
      return false;
    case Recovery::Confirm:
      if (sw_seq_ <= read_sw_seq_) return false;  // no TPDO since the read
      if (needs_comm_reset_ || emcy_errors_ != read_emcy_ || state_ != read_state_ ||
          (word & faulty) != 0) {
        // it changed since: read again (a frozen TPDO that never agrees
        // with the drive's own word ends it)
        read_again(emcy_errors_ != read_emcy_ ? std::string(kEmcysKeptComing)
                   : state_ != read_state_
                       ? "the drive's statusword read by SDO (" +
                             std::string(to_string(read_state_)) + ") and its TPDO (" +
                             to_string(state_) + ", " + hex(word, 4) + ") kept disagreeing"
                       : std::string("its TPDO kept showing a fault or a ") + mode_->error_name() +
                             " (" + hex(word, 4) + ")");
        return false;
      }
      fault_ = FaultCode::None;
      fault_name_.clear();
      last_warning_.clear();
      recovery_ = Recovery::None;
      return true;
    case Recovery::ResetLow:
      // a statusword since 0x0000 went out: the drive has sampled it
      if (sw_seq_ > low_seq_ || now_s - low_t_ >= s_.fault_reset_low_s) {
        send_rpdo(cw::kCmdFaultReset, out);
        reset_seq_ = sw_seq_;
        recovery_ = Recovery::WaitFresh;
      }
      return false;
    case Recovery::WaitFresh:
      // A fault reset takes the drive to Switch on disabled (CiA 402
      // transition 15): only that state, in a statusword received after the
      // reset went out, clears the latch. A frozen TPDO that still says
      // Operation enabled, or any other state, proves nothing.
      if (!(sw_ && sw_seq_ > reset_seq_ && (word & faulty) == 0 &&
            state_ == State::SwitchOnDisabled))
        return false;
      if (needs_comm_reset_) {  // only a reconfiguration clears that
        recovery_ = Recovery::AfterComm;
        reset_comm(now_s, out);
        return false;
      }
      fault_ = FaultCode::None;
      fault_name_.clear();
      last_warning_.clear();
      recovery_ = Recovery::None;
      return true;
    case Recovery::None:
      return true;
  }
  return true;
}

void Master::on_status_read(double now_s, std::vector<can::Frame>& out) {
  const canopen::SdoResult r = std::move(*status_read_);
  status_read_.reset();
  // A boot-up or a lost heartbeat since: the drive's objects may be its
  // defaults, only a reconfiguration clears that
  if (needs_comm_reset_) {
    recovery_ = Recovery::AfterComm;
    reset_comm(now_s, out);
    return;
  }
  // An EMCY since the read went out may be a new fault its answer does not
  // show (an EMCY outranks the SDO answer on the bus)
  if (emcy_errors_ != read_emcy_) return read_again(kEmcysKeptComing);
  // expedited, with or without the size indicated (CiA 301): 2 to 4 bytes
  if (!r.ok() || r.data.size() < 2 || r.data.size() > 4) {
    // nothing known, nothing sent: the latch stays, the next Enable tries
    // again (a silent drive latches its heartbeat loss)
    recovery_ = Recovery::None;
    fault_name_ = base_fault_name() + "; the statusword could not be read for its reset: " +
                  (r.ok() ? std::to_string(r.data.size()) + " bytes" : r.describe());
    return;
  }
  const auto read = static_cast<std::uint16_t>(get_le(r.data, 0, 2));
  const State drive = decode_state(read);
  if (drive == State::FaultReactionActive) {
    // the drive still reacts to its fault (it may be braking): ask again
    if (++fault_reaction_reads_ > kFaultReactionReads) {
      recovery_ = Recovery::None;
      fault_name_ = base_fault_name() + "; the drive stayed in fault reaction active";
      return;
    }
    recovery_ = Recovery::SendReset;
    status_read_at_ = now_s + s_.fault_reset_low_s;
    return;
  }
  if (drive == State::Unknown) {
    // no state CiA 402 codes: neither a reset nor an enable
    recovery_ = Recovery::None;
    fault_name_ =
        base_fault_name() + "; the drive's statusword " + hex(read, 4) + " codes no CiA 402 state";
    return;
  }
  if (drive != State::Fault) {
    if (drive == State::OperationEnabled && (read & mode_->error_bits()) != 0) {
      recovery_ = Recovery::None;  // a following error that lasts: the latch stays
      fault_name_ = base_fault_name() + "; the " + mode_->error_name() + " lasts (statusword " +
                    hex(read, 4) + ")";
      return;
    }
    // Not in fault, by the drive's own word (a lost heartbeat, an EMCY that
    // only warned, a set-point timeout): nothing to reset. The TPDO state
    // the controlword is chosen from must agree first.
    read_state_ = drive;
    recovery_ = Recovery::Confirm;
    return;
  }
  // In fault, its power stage off: the reset is a rising edge of bit 7, and
  // RPDO1 an overwrite buffer the drive samples once a cycle: a 0x0000 sent
  // with 0x0080 right behind it may never be seen. Bit 7 low first, when
  // the drive may hold it high (or we do not know), and the edge later.
  if (!cw_sent_ || (cw_ & cw::kFaultReset) != 0) {
    send_rpdo(cw::kCmdDisableVoltage, out);
    low_seq_ = sw_seq_;
    low_t_ = now_s;
    recovery_ = Recovery::ResetLow;
    return;
  }
  send_rpdo(cw::kCmdFaultReset, out);
  reset_seq_ = sw_seq_;
  recovery_ = Recovery::WaitFresh;
}

bool Master::acknowledge(double now_s, std::vector<can::Frame>& out, bool timeouts) {
  const std::uint16_t word = sw_.value_or(0);
  const bool fresh_after_ack = sw_ && sw_seq_ > ack_after_;
  switch (ack_on_) {
    case AckOn::Enabled:
      if (state_ == State::OperationEnabled) ack_on_ = AckOn::None, ack_ = ack_seq_;
      break;
    case AckOn::Disabled:
      if (state_ == State::ReadyToSwitchOn || state_ == State::SwitchOnDisabled ||
          state_ == State::NotReadyToSwitchOn)
        ack_on_ = AckOn::None, ack_ = ack_seq_;
      break;
    case AckOn::Halted:
      if (fresh_after_ack) ack_on_ = AckOn::None, ack_ = ack_seq_;
      break;
    case AckOn::Stopped:
    case AckOn::None:
      break;
  }
  // the mode's handshake (profile position: the set-point's)
  if (state_ != State::OperationEnabled) {
    mode_->left_enabled();
    return true;
  }
  const ModeProgress p = mode_->on_status(word, sw_seq_, fresh_after_ack, now_s, timeouts);
  if (p.acked) ack_ = *p.acked;
  if (!p.fault.empty()) {
    latch(FaultCode::SetPointTimeout, p.fault);
    send_rpdo(cw::kCmdEnableOperation | motion_bits(), out);  // the set-point's bit down
    return false;
  }
  return true;
}

std::optional<std::uint16_t> Master::towards_goal(bool& set_point) {
  const std::uint16_t word = sw_.value_or(0);
  std::uint16_t want = cw_;
  switch (goal_) {
    case Goal::Disabled:
      // Shutdown (transition 8 from Operation enabled): the drive stops on
      // its ramp before it lets go, where Disable voltage (9) lets a moving
      // table coast. From Quick stop active only Disable voltage (12) leads
      // out: sent once the quick stop is complete (quick_stop_done).
      // Switch on disabled stays so (Disable voltage holds it there).
      if (state_ == State::QuickStopActive) {
        if (quick_stop_done(word)) want = cw::kCmdDisableVoltage;
      } else if (state_ == State::SwitchOnDisabled || state_ == State::NotReadyToSwitchOn) {
        want = cw::kCmdDisableVoltage;
      } else if (state_ == State::OperationEnabled && rest_since_running().state != Rest::AtRest) {
        // Shutdown lets a turning table coast on a drive without 0x605B:
        // it waits, enabled and halted, for the table known at rest (the
        // halt kept or set: a halted move taken up again is no way to rest)
        want = cw::kCmdEnableOperation | motion_bits() | cw::kHalt;
      } else {
        want = cw::kCmdShutdown;
      }
      return want;
    case Goal::QuickStop:
      return cw::kCmdQuickStop;
    case Goal::Enabled:
      break;
  }
  switch (state_) {
    case State::SwitchOnDisabled:
      return cw::kCmdShutdown;  // transition 2
    case State::ReadyToSwitchOn:
      return cw::kCmdSwitchOn;  // 3
    case State::SwitchedOn: {
      // 4: the drive holds its actual position from here. Onto a table that
      // still turns (a drive that let go, a run that ended with the table
      // coasting) it would brake the instrument at the drive's full torque:
      // only with the table known at rest (TPDO1's positions since the NMT
      // start, rest_since_running()); until then Switched on stays
      // (whatever went out before a reset).
      const Rest rest = rest_since_running();
      if (rest.state == Rest::Unknown) return cw::kCmdSwitchOn;
      if (rest.state == Rest::Turning) {
        latch(FaultCode::TurningAtEnable,
              "not enabled: the table turns at " + num(rest.rate_rps * kRadToDeg) +
                  " deg/s with the drive switched on but not enabled; enabling would brake "
                  "it at the drive's full torque: let it stop, then enable");
        return std::nullopt;
      }
      return cw::kCmdEnableOperation;
    }
    case State::OperationEnabled:
      return static_cast<std::uint16_t>(cw::kCmdEnableOperation | motion_bits() |
                                        mode_->set_point_bits(word, set_point));
    case State::QuickStopActive:
      // 12, then up again; not before the quick stop is complete: Disable
      // voltage while still decelerating lets it coast
      if (quick_stop_done(word)) want = cw::kCmdDisableVoltage;
      return want;
    default:
      return want;  // not ready, fault reaction, fault: the drive moves on by itself
  }
}

bool Master::quick_stop_done(std::uint16_t word) const {
  // Bit 10 (target reached) in quick stop active: set by many drives once
  // at rest, but CiA 402 defines it there for profile modes only, and not
  // every drive sets it. The table known at rest from its own positions
  // (TPDO1 since the NMT start) is as good.
  return (word & sw::kTargetReached) != 0 || rest_since_running().state == Rest::AtRest;
}

std::string Master::why_no_move() const {
  if (phase_ == CommPhase::Running && fault_ == FaultCode::None && goal_ == Goal::Enabled &&
      state_ == State::OperationEnabled)
    return {};
  return std::string("a move needs the drive enabled (CiA 402 state: ") + to_string(state_) +
         (fault_ != FaultCode::None ? ", fault: " + fault_name_ : "") + ")";
}

Status Master::enable(std::uint8_t seq, double now_s, std::vector<can::Frame>& out) {
  // Onto a turning table (a warning latched mid-move, a drive that let go
  // and coasts) an enable would set a new demand at speed (by the rest test
  // the enable itself waits for: one verdict)
  if (const Rest rest = rest_since_running();
      phase_ == CommPhase::Running && rest.state == Rest::Turning)
    return make_error("enable refused while the table turns (" + num(rest.rate_rps * kRadToDeg) +
                      " deg/s): stop it first (quick stop), or wait for it to stop");
  goal_ = Goal::Enabled;
  quick_stopped_ = false;
  halted_ = false;
  fault_reaction_reads_ = 0;  // each Enable's recovery has its own bounds
  confirm_reads_ = 0;
  mode_->reset();
  ack_on_ = AckOn::Enabled;
  ack_seq_ = seq;
  // a fault reset already tried and still no statusword without fault: this
  // Enable tries again
  if (fault_ != FaultCode::None &&
      (recovery_ == Recovery::None || recovery_ == Recovery::WaitFresh ||
       recovery_ == Recovery::Confirm)) {
    if (needs_comm_reset_ || phase_ == CommPhase::Failed) {
      recovery_ = Recovery::AfterComm;
      reset_comm(now_s, out);
    } else {
      recovery_ = Recovery::SendReset;
      low_t_ = now_s;
    }
  } else if (phase_ == CommPhase::Failed) {
    reset_comm(now_s, out);
  }
  return Ok{};
}

Status Master::disable(std::uint8_t seq) {
  const bool running = phase_ == CommPhase::Running;
  if (running && fault_ == FaultCode::None && goal_ == Goal::Enabled &&
      state_ == State::OperationEnabled && mode_->moving())
    return make_error(
        "disable refused while the table moves: stop it first (controlled or quick stop)");
  // whatever the master thinks of its move: a drive without 0x605B/C lets
  // a turning table coast on Shutdown
  if (const Rest rest = rest_since_running(); running && rest.state == Rest::Turning)
    return make_error("disable refused while the table turns (" + num(rest.rate_rps * kRadToDeg) +
                      " deg/s): stop it first (quick stop), or wait for it to stop");
  goal_ = Goal::Disabled;
  abandon_recovery();
  quick_stopped_ = false;
  mode_->reset();
  ack_seq_ = seq;
  ack_on_ = AckOn::Disabled;
  if (!running) ack_ = seq, ack_on_ = AckOn::None;
  return Ok{};
}

Status Master::quick_stop(std::uint8_t seq, double now_s, std::vector<can::Frame>& out) {
  goal_ = Goal::QuickStop;
  quick_stopped_ = true;
  mode_->reset();
  ack_seq_ = seq;
  ack_on_ = AckOn::Stopped;
  ack_after_ = sw_seq_;
  abandon_recovery();  // the next Enable tries again
  if (phase_ == CommPhase::Running) {
    // at once, whatever the fault latch: the drive is told to stop, and the
    // ack waits for a statusword that shows it (quick stop active, fault,
    // or not enabled): an EMCY may be a mere warning
    send_rpdo(cw::kCmdQuickStop, out);
    evaluate(now_s, out);
    return Ok{};
  }
  if (phase_ == CommPhase::WaitBootUp)
    return make_error(
        "quick stop not sent: the drive's communication is being reset (no SDO before its "
        "boot-up); send it again");
  // Configuring or Failed: no PDO, but an SDO reaches the drive in
  // pre-operational, and after a communication reset it may still be
  // enabled. The answer to the write is the ack; it goes before the
  // configuration's queued writes, and is kept when it fails.
  sdo_.download_urgent(obj::kControlword, 0, le_bytes(cw::kCmdQuickStop, 2),
                       [this, seq](const canopen::SdoResult& r) {
                         if (ack_on_ != AckOn::Stopped || ack_seq_ != seq) return;
                         ack_on_ = AckOn::None;
                         if (r.ok())
                           ack_ = seq;
                         else
                           latch(FaultCode::Sdo,
                                 "quick stop by SDO (0x6040) failed: " + r.describe());
                       });
  sdo_.tick(now_s, out);
  return Ok{};
}

Status Master::controlled_stop(std::uint8_t seq, double now_s, std::vector<can::Frame>& out) {
  const bool running = phase_ == CommPhase::Running;
  ack_seq_ = seq;
  if (running && fault_ == FaultCode::None && state_ == State::OperationEnabled &&
      goal_ == Goal::Enabled) {
    halted_ = true;
    mode_->halt();
    ack_on_ = AckOn::Halted;
    ack_after_ = sw_seq_;
    send_rpdo(cw::kCmdEnableOperation | motion_bits(), out);
  } else if (running && fault_ != FaultCode::None) {
    // a latched fault (an EMCY that only warned, the drive that left
    // operation enabled) and the table may turn: a quick stop, acked as one
    // when the drive shows it
    return quick_stop(seq, now_s, out);
  } else {
    ack_ = seq;  // nothing moves
    ack_on_ = AckOn::None;
  }
  return Ok{};
}

Status Master::command(TableCommandCode code, std::uint8_t seq, double target_rad, double rate_rps,
                       double now_s, std::vector<can::Frame>& out) {
  now_ = std::max(now_, now_s);
  if (!invalid_.empty()) return make_error("invalid CANopen master settings: " + invalid_);
  if (phase_ == CommPhase::Idle) return make_error("the CANopen master has not been started");
  switch (code) {
    case TableCommandCode::Enable:
      TURNCAL_TRY(enable(seq, now_s, out));
      break;
    case TableCommandCode::Disable:
      TURNCAL_TRY(disable(seq));
      break;
    case TableCommandCode::QuickStop:
      return quick_stop(seq, now_s, out);
    case TableCommandCode::ControlledStop:
      TURNCAL_TRY(controlled_stop(seq, now_s, out));
      break;
    case TableCommandCode::MoveAbsolute:
    case TableCommandCode::MoveRelative:
      TURNCAL_TRY(mode_->move(code, seq, target_rad, rate_rps, now_s, out));
      halted_ = false;
      break;
    default:
      return make_error("unknown table command code " + std::to_string(static_cast<int>(code)));
  }
  evaluate(now_s, out);
  return Ok{};
}

TableView Master::status() const {
  TableView v;
  v.ack = ack_;
  // a rate older than the drive's heartbeat timeout is not known
  if (s_.velocity_pdo)
    v.rate_rps = now_ - velocity_t_ <= s_.drive_heartbeat_timeout_s ? velocity_ : std::nan("");
  else
    v.rate_rps = now_ - last_tpdo_t_ <= s_.drive_heartbeat_timeout_s ? rate_ : std::nan("");
  if (fault_ != FaultCode::None) {
    v.state = TableState::Fault;
    v.fault = fault_;
    v.fault_name = fault_name_;
    return v;
  }
  if (phase_ != CommPhase::Running || !sw_) {
    v.state = quick_stopped_ ? TableState::QuickStopped : TableState::Disabled;
    return v;
  }
  switch (state_) {
    case State::OperationEnabled:
      v.state = mode_->enabled_state();
      break;
    case State::QuickStopActive:
      v.state = TableState::QuickStopped;
      break;
    case State::FaultReactionActive:
    case State::Fault:
      v.state = TableState::Fault;
      v.fault = FaultCode::DriveFault;
      v.fault_name = "drive in fault";
      break;
    default:
      v.state = quick_stopped_ ? TableState::QuickStopped : TableState::Disabled;
      break;
  }
  return v;
}

void Master::take_samples(std::vector<EncoderSample>& out) {
  out.insert(out.end(), samples_.begin(), samples_.end());
  samples_.clear();
}

void Master::read(std::uint16_t index, std::uint8_t sub, canopen::SdoClient::Callback done) {
  sdo_.upload(index, sub, std::move(done));
}

void Master::write(std::uint16_t index, std::uint8_t sub, std::vector<std::uint8_t> data,
                   canopen::SdoClient::Callback done) {
  sdo_.download(index, sub, std::move(data), std::move(done));
}

}  // namespace turncal::cia402
