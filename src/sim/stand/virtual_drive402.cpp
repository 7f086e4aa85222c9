#include "turncal/sim/virtual_drive402.hpp"

#include <algorithm>

#include "turncal/sim/earliest.hpp"

namespace turncal::stand {

using facts::get_le;
using facts::put_le;
using facts::State;
namespace ac = facts::abort;
namespace obj = facts::od;
namespace cob = facts::cob;
using Nmt = facts::Nmt;

namespace {

constexpr std::uint32_t key_of(std::uint16_t index, std::uint8_t sub) {
  return static_cast<std::uint32_t>(index) << 8 | sub;
}
constexpr std::uint16_t index_of(std::uint32_t key) {
  return static_cast<std::uint16_t>(key >> 8);
}
constexpr std::uint8_t sub_of(std::uint32_t key) {
  return static_cast<std::uint8_t>(key & 0xFF);
}

constexpr double kTwoPi = 6.283185307179586;
constexpr double kDeg = 0.017453292519943295;
constexpr std::size_t kMaxString = 64;

can::Frame frame8(std::uint32_t id) {
  can::Frame f;
  f.id = id;
  f.len = 8;
  return f;
}

}  // namespace

VirtualDrive402::VirtualDrive402(const Drive402Setup& setup, const Drive402Faults& faults)
    : setup_(setup),
      faults_(faults),
      cpr_(setup.counts_per_rev * setup.gear_ratio / kTwoPi),
      motion_(setup.angle0_rad) {
  build_dictionary();
  booting_ = true;
  boot_at_ = setup_.power_on_s + setup_.boot_delay_s;
  demand_ = position_counts(setup_.power_on_s);
  last_target_ = demand_;
  if (setup_.cycle_s > 0) next_cycle_ = setup_.power_on_s + setup_.cycle_s;
}

void VirtualDrive402::add(std::uint16_t index, std::uint8_t sub, Entry e) {
  od_[key_of(index, sub)] = std::move(e);
}

void VirtualDrive402::build_dictionary() {
  auto uns = [](std::uint8_t size, bool w, std::uint64_t v, bool map = false, std::int64_t lo = 0,
                std::int64_t hi = -1) {
    Entry e;
    e.size = size;
    e.writable = w;
    e.mappable = map;
    e.min = lo;
    e.max = hi >= 0 ? hi : static_cast<std::int64_t>((std::uint64_t{1} << (8 * size)) - 1);
    e.value = facts::le_bytes(v, size);
    return e;
  };
  auto sgn = [](std::uint8_t size, bool w, std::int64_t v, bool map, std::int64_t lo,
                std::int64_t hi) {
    Entry e;
    e.size = size;
    e.writable = w;
    e.mappable = map;
    e.is_signed = true;
    e.min = lo;
    e.max = hi;
    e.value = facts::le_bytes(static_cast<std::uint64_t>(v), size);
    return e;
  };
  auto str = [](const std::string& s) {
    Entry e;
    e.value.assign(s.begin(), s.end());
    return e;
  };
  const std::uint8_t node = setup_.node_id;
  add(obj::kDeviceType, 0, uns(4, false, facts::od::kServoDrive402));
  add(obj::kErrorRegister, 0, uns(1, false, 0));
  add(obj::kDeviceName, 0, str(setup_.device_name));
  add(obj::kSoftwareVersion, 0, str("1.0"));
  Entry label = str("");
  label.writable = true;
  add(obj::kLabel, 0, label);  // a stand label, written and read by segmented SDO
  add(obj::kConsumerHeartbeat, 0, uns(1, false, 1));
  add(obj::kConsumerHeartbeat, 1, uns(4, true, 0));
  add(obj::kProducerHeartbeat, 0, uns(2, true, setup_.producer_heartbeat_ms));
  add(obj::kIdentity, 0, uns(1, false, 4));
  add(obj::kIdentity, 1, uns(4, false, 0));
  add(obj::kIdentity, 2, uns(4, false, 0x402));
  add(obj::kIdentity, 3, uns(4, false, 1));
  add(obj::kIdentity, 4, uns(4, false, 1));
  const bool map = setup_.default_mapping;
  add(obj::kRpdo1Comm, 0, uns(1, false, 2));
  add(obj::kRpdo1Comm, 1, uns(4, true, cob::kRpdo1 + node));
  add(obj::kRpdo1Comm, 2, uns(1, true, 0xFF));
  add(obj::kRpdo1Map, 0, uns(1, true, map ? 2 : 0, false, 0, 8));
  for (std::uint8_t i = 1; i <= 8; ++i) add(obj::kRpdo1Map, i, uns(4, true, 0));
  add(obj::kTpdo1Comm, 0, uns(1, false, 5));
  add(obj::kTpdo1Comm, 1, uns(4, true, cob::kTpdo1 + node));
  add(obj::kTpdo1Comm, 2, uns(1, true, setup_.tpdo_transmission_type));
  add(obj::kTpdo1Comm, 3, uns(2, true, 0));
  add(obj::kTpdo1Comm, 5, uns(2, true, setup_.tpdo_event_timer_ms));
  add(obj::kTpdo1Map, 0, uns(1, true, map ? 2 : 0, false, 0, 8));
  for (std::uint8_t i = 1; i <= 8; ++i) add(obj::kTpdo1Map, i, uns(4, true, 0));
  // TPDO2: not valid and empty until a master maps it (velocity actual)
  add(obj::kTpdo2Comm, 0, uns(1, false, 5));
  add(obj::kTpdo2Comm, 1, uns(4, true, 0x80000000u | (cob::kTpdo2 + node)));
  add(obj::kTpdo2Comm, 2, uns(1, true, 0xFF));
  add(obj::kTpdo2Comm, 3, uns(2, true, 0));
  add(obj::kTpdo2Comm, 5, uns(2, true, 0));
  add(obj::kTpdo2Map, 0, uns(1, true, 0, false, 0, 8));
  for (std::uint8_t i = 1; i <= 8; ++i) add(obj::kTpdo2Map, i, uns(4, true, 0));
  if (map) {
    set(obj::kRpdo1Map, 1, 0x60400010);
    set(obj::kRpdo1Map, 2, 0x607A0020);
    set(obj::kTpdo1Map, 1, 0x60410010);
    set(obj::kTpdo1Map, 2, 0x60640020);
  }
  add(obj::kAbortConnectionOption, 0, sgn(2, true, 1, false, 0, 3));
  add(obj::kErrorCode, 0, uns(2, false, 0));
  add(obj::kControlword, 0, uns(2, true, 0, true));
  add(obj::kStatusword, 0, uns(2, false, 0, true));
  add(obj::kQuickStopOption, 0, sgn(2, true, 2, false, 0, 8));
  // 0 (the default of many drives): the power stage lets go at once
  add(obj::kShutdownOption, 0, sgn(2, true, 0, false, -32768, 1));
  add(obj::kDisableOperationOption, 0, sgn(2, true, 0, false, -32768, 1));
  add(obj::kModesOfOperation, 0, sgn(1, true, 0, false, -128, 127));
  add(obj::kModesDisplay, 0, sgn(1, false, 0, false, -128, 127));
  add(obj::kPositioningOption, 0, uns(2, true, setup_.positioning_option));
  constexpr std::int64_t kS32Min = -2147483648LL, kS32Max = 2147483647LL;
  add(obj::kPositionActual, 0, sgn(4, false, 0, true, kS32Min, kS32Max));
  add(obj::kVelocityActual, 0, sgn(4, false, 0, true, kS32Min, kS32Max));
  add(obj::kTargetPosition, 0, sgn(4, true, 0, true, kS32Min, kS32Max));
  add(obj::kMaxProfileVelocity, 0, uns(4, true, setup_.max_profile_velocity));
  auto counts = [&](double per_s) {
    return static_cast<std::uint64_t>(std::max(1.0, std::round(per_s * cpr_)));
  };
  add(obj::kProfileVelocity, 0, uns(4, true, counts(10 * kDeg), false, 1));
  add(obj::kProfileAcceleration, 0, uns(4, true, counts(10 * kDeg), false, 1));
  add(obj::kProfileDeceleration, 0, uns(4, true, counts(10 * kDeg), false, 1));
  add(obj::kQuickStopDeceleration, 0, uns(4, true, counts(90 * kDeg), false, 1));
  for (const auto& [k, e] : od_) (index_of(k) < 0x2000 ? comm_defaults_ : app_defaults_)[k] = e;
}

std::int64_t VirtualDrive402::integer(const Entry& e) const {
  std::uint64_t raw = 0;
  for (std::size_t i = 0; i < e.value.size() && i < 8; ++i)
    raw |= static_cast<std::uint64_t>(e.value[i]) << (8 * i);
  if (e.is_signed && e.size > 0 && e.size < 8) {
    const std::uint64_t sign = std::uint64_t{1} << (8 * e.size - 1);
    if ((raw & sign) != 0) raw |= ~((sign << 1) - 1);
  }
  return static_cast<std::int64_t>(raw);
}

std::uint32_t VirtualDrive402::u32(std::uint16_t index, std::uint8_t sub) const {
  const auto it = od_.find(key_of(index, sub));
  return it == od_.end() ? 0 : static_cast<std::uint32_t>(integer(it->second));
}

void VirtualDrive402::set(std::uint16_t index, std::uint8_t sub, std::int64_t v) {
  Entry& e = od_.at(key_of(index, sub));
  put_le(e.value, 0, e.size, static_cast<std::uint64_t>(v));
}

std::optional<std::int64_t> VirtualDrive402::value(std::uint16_t index, std::uint8_t sub) const {
  const auto it = od_.find(key_of(index, sub));
  if (it == od_.end() || it->second.size == 0) return std::nullopt;
  return integer(it->second);
}

std::int64_t VirtualDrive402::position_counts(double t) const {
  return std::llround(sense() * motion_.at(t).angle * cpr_);
}

std::uint16_t VirtualDrive402::statusword() const {
  std::uint16_t s = facts::state_bits(state_) | facts::sw::kRemote;
  if (state_ == State::ReadyToSwitchOn || state_ == State::SwitchedOn ||
      state_ == State::OperationEnabled || state_ == State::QuickStopActive ||
      state_ == State::FaultReactionActive)
    s |= facts::sw::kVoltageEnabled;
  if (target_reached_ &&
      (state_ == State::OperationEnabled ||
       (state_ == State::QuickStopActive && setup_.target_reached_in_quick_stop)))
    s |= facts::sw::kTargetReached;
  if ((set_point_ack_ || enable_ack_) && state_ == State::OperationEnabled)
    s |= facts::sw::kSetPointAcknowledge;
  if (following_error_) s |= facts::sw::kFollowingError;
  if (setup_.quick_stop_bit_where_free &&
      (state_ == State::NotReadyToSwitchOn || state_ == State::SwitchOnDisabled ||
       state_ == State::FaultReactionActive || state_ == State::Fault))
    s |= 1u << 5;  // table 30: x in these states
  if (warning_) s |= facts::sw::kWarning;
  return s;
}

bool VirtualDrive402::silent(double t) const {
  return t >= faults_.silent_at_s && t < faults_.silent_until_s;
}

void VirtualDrive402::emit(double t, const can::Frame& f, std::vector<DriveFrame>& out) {
  if (!silent(t)) out.push_back({t, f});
}

void VirtualDrive402::answer_sdo(double t, const can::Frame& f, std::vector<DriveFrame>& out) {
  const double lo = setup_.sdo_answer_min_s, hi = std::max(lo, setup_.sdo_answer_max_s);
  if (hi <= 0) return emit(t, f, out);
  // spread over [lo, hi] by the golden ratio's fractions: every delay
  // between, none twice in a row, the same sequence each run; never
  // before an answer already due (one server, its answers in order)
  sdo_spread_ = std::fmod(sdo_spread_ + 0.6180339887498949, 1.0);
  const double due = t + lo + (hi - lo) * sdo_spread_;
  sdo_due_.push_back({sdo_due_.empty() ? due : std::max(due, sdo_due_.back().t_s), f});
}

void VirtualDrive402::emcy(double t, std::uint16_t code, std::uint8_t reg,
                           std::vector<DriveFrame>& out) {
  set(obj::kErrorRegister, 0, reg);
  if (code != 0) set(obj::kErrorCode, 0, code);
  emcy_sent_.push_back(code);
  if (!booting_ && nmt_ != Nmt::Stopped) emit(t, facts::emcy(setup_.node_id, code, reg), out);
}

void VirtualDrive402::reset_communication(double t) {
  for (const auto& [k, e] : comm_defaults_) od_[k] = e;
  booting_ = true;
  boot_at_ = t + setup_.boot_delay_s;
  next_hb_ = std::numeric_limits<double>::infinity();
  host_last_hb_ = NAN;
  sdo_due_.clear();  // the server restarts: answers not yet sent are never sent
  sdo_ = Transfer{};
  next_tpdo_ = std::numeric_limits<double>::infinity();
  last_sent_sw_.reset();
  sync_count_ = 0;
  rpdo_buf_.reset();
  ++counts_.nmt_resets;
}

// ---- time ----

void VirtualDrive402::advance(double t, std::vector<DriveFrame>& out) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  for (;;) {
    Earliest next(t);
    const auto consider = [&](double at, int id) { next.consider(at, id); };
    if (booting_) consider(boot_at_, 0);
    if (!booting_) consider(next_hb_, 1);
    const std::uint32_t consumer = u32(obj::kConsumerHeartbeat, 1);
    if ((consumer & 0xFFFF) != 0 && !std::isnan(host_last_hb_))
      consider(host_last_hb_ + (consumer & 0xFFFF) / 1000.0, 2);
    consider(faults_.fault_at_s, 3);
    consider(faults_.following_error_at_s, 4);
    consider(faults_.warning_at_s, 9);
    if (motion_kind_ != Motion::Rest) consider(rest_at_, 5);
    if (nmt_ == Nmt::Operational && !booting_) consider(next_tpdo_, 6);
    consider(next_cycle_, 7);
    consider(mode_at_, 8);
    consider(enable_ack_until_, 10);
    if (!sdo_due_.empty()) consider(sdo_due_.front().t_s, 11);
    consider(fault_state_at_, 12);
    const std::uint16_t hb_ms = static_cast<std::uint16_t>(u32(obj::kProducerHeartbeat));
    const double when = next.when();
    switch (next.which()) {
      case 0:
        booting_ = false;
        nmt_ = Nmt::PreOperational;
        emit(when, facts::heartbeat(setup_.node_id, Nmt::BootUp), out);
        next_hb_ = hb_ms > 0 ? when + hb_ms / 1000.0 : kInf;
        if (setup_.boot_warning_code != 0) {
          warning_ = true;
          boot_warning_ = true;
          emcy(when, setup_.boot_warning_code, 0x01, out);  // generic error
        }
        break;
      case 1:
        emit(when, facts::heartbeat(setup_.node_id, nmt_), out);
        next_hb_ = hb_ms > 0 ? next_hb_ + hb_ms / 1000.0 : kInf;
        break;
      case 2:
        host_heartbeat_lost(when, out);
        break;
      case 3:
        faults_.fault_at_s = NAN;
        if (faults_.fault_state_after_emcy_s > 0) {
          emcy(when, faults_.fault_code, 0x01, out);
          fault_state_at_ = when + faults_.fault_state_after_emcy_s;
        } else {
          fault(when, faults_.fault_code, out);
        }
        break;
      case 12:
        fault_state_at_ = kInf;
        if (state_ != State::Fault && state_ != State::FaultReactionActive) {
          set_point_ack_ = false;
          enter(State::FaultReactionActive);
          stop_motion(when, u32(obj::kQuickStopDeceleration), Motion::FaultStop);
        }
        break;
      case 4:
        faults_.following_error_at_s = NAN;
        if (state_ == State::OperationEnabled) {
          following_error_ = true;
          fault(when, 0x8611, out);
        }
        break;
      case 5:
        at_rest(when, out);
        break;
      case 6: {
        if (setup_.cycle_s > 0)
          timer_due_ = true;  // at the next cycle
        else
          send_tpdo(when, out);
        const std::uint16_t timer = static_cast<std::uint16_t>(u32(obj::kTpdo1Comm, 5));
        next_tpdo_ = event_driven() && timer > 0 ? when + timer / 1000.0 : kInf;
        break;
      }
      case 7:
        cycle(when, out);
        break;
      case 9:
        faults_.warning_at_s = NAN;
        warning_ = true;
        emcy(when, faults_.warning_code, 0x09, out);  // generic + temperature
        break;
      case 11:
        emit(when, sdo_due_.front().frame, out);
        sdo_due_.pop_front();
        break;
      case 10:
        enable_ack_ = false;
        enable_ack_until_ = kInf;
        break;
      case 8:
        mode_at_ = kInf;
        set(obj::kModesDisplay, 0, static_cast<std::int64_t>(u32(obj::kModesOfOperation)));
        break;
      default:
        now_ = std::max(now_, t);
        return;
    }
    now_ = std::max(now_, when);
    tpdo_on_change(when, out);
  }
}

void VirtualDrive402::receive(double t, const can::Frame& f, std::vector<DriveFrame>& out) {
  advance(t, out);
  if (silent(t) || f.extended || f.error || f.remote || f.fd) return;
  const std::uint8_t node = setup_.node_id;
  const std::uint32_t consumer = u32(obj::kConsumerHeartbeat, 1);
  const std::uint32_t rpdo = u32(obj::kRpdo1Comm, 1);
  if (f.id == cob::kNmt) {
    on_nmt(t, f, out);
  } else if (facts::on_sync_id(f)) {
    // CiA 301: no data, or one byte of counter; other lengths are no SYNC
    if (facts::is_sync(f)) {
      on_sync(t, out);
    } else {
      ++counts_.malformed;
    }
  } else if (f.id == cob::kSdoRx + node) {
    on_sdo(t, f, out);
  } else if ((rpdo & 0x80000000u) == 0 && f.id == (rpdo & 0x7FF)) {
    on_rpdo(t, f, out);
  } else if ((consumer & 0xFFFF) != 0 && f.id == cob::kHeartbeat + ((consumer >> 16) & 0x7F)) {
    if (f.len != 1) {
      ++counts_.malformed;
    } else {
      ++counts_.host_heartbeats;
      host_last_hb_ = t;
    }
  }
  advance(t, out);  // what the frame made due at once
  tpdo_on_change(t, out);
}

// ---- NMT, SYNC ----

void VirtualDrive402::on_nmt(double t, const can::Frame& f, std::vector<DriveFrame>& out) {
  if (f.len != 2) {
    ++counts_.malformed;
    return;
  }
  if (f.data[1] != 0 && f.data[1] != setup_.node_id) return;
  if (booting_) return;
  switch (f.data[0]) {
    case facts::nmt::kStart:
      nmt_ = Nmt::Operational;
      if (boot_warning_) {  // gone once operational: error reset
        boot_warning_ = false;
        warning_ = false;
        emcy(t, 0x0000, 0, out);
      }
      sync_count_ = 0;
      if (event_driven()) send_tpdo(t, out);
      break;
    case facts::nmt::kStop:
      nmt_ = Nmt::Stopped;
      break;
    case facts::nmt::kEnterPreOperational:
      nmt_ = Nmt::PreOperational;
      break;
    case facts::nmt::kResetNode:
      coast(t);  // the application restarts: its power stage lets go
      enter(State::SwitchOnDisabled);
      // its objects to their power-on values too (0x6041, 0x6064 and the
      // like are refreshed from the drive's state when read)
      for (const auto& [k, e] : app_defaults_) od_[k] = e;
      mode_at_ = std::numeric_limits<double>::infinity();
      reset_communication(t);
      break;
    case facts::nmt::kResetCommunication:
      reset_communication(t);
      break;
    default:
      ++counts_.malformed;
      break;
  }
}

void VirtualDrive402::on_sync(double t, std::vector<DriveFrame>& out) {
  if (nmt_ != Nmt::Operational) return;
  ++counts_.sync;
  const std::uint32_t type = u32(obj::kTpdo1Comm, 2);
  if (type >= 1 && type <= 240 && ++sync_count_ % type == 0) send_tpdo(t, out);
}

// ---- SDO server ----

void VirtualDrive402::sdo_abort(double t, std::uint32_t key, std::uint32_t code,
                                std::vector<DriveFrame>& out) {
  can::Frame r = frame8(cob::kSdoTx + setup_.node_id);
  r.data[0] = 0x80;
  put_le(r.data, 1, 2, index_of(key));
  r.data[3] = sub_of(key);
  put_le(r.data, 4, 4, code);
  answer_sdo(t, r, out);
  ++counts_.sdo_aborts;
  sdo_.active = false;
}

std::uint32_t VirtualDrive402::read(double t, std::uint32_t key, std::vector<std::uint8_t>& data) {
  refresh(t);
  const auto it = od_.find(key);
  if (it == od_.end()) {
    const auto lo = od_.lower_bound(key & ~0xFFu);
    return lo != od_.end() && index_of(lo->first) == index_of(key) ? ac::kNoSubindex
                                                                   : ac::kNoObject;
  }
  data = it->second.value;
  return 0;
}

std::uint32_t VirtualDrive402::write(double t, std::uint32_t key,
                                     const std::vector<std::uint8_t>& data,
                                     std::vector<DriveFrame>& out) {
  const auto it = od_.find(key);
  if (it == od_.end()) {
    const auto lo = od_.lower_bound(key & ~0xFFu);
    return lo != od_.end() && index_of(lo->first) == index_of(key) ? ac::kNoSubindex
                                                                   : ac::kNoObject;
  }
  Entry& e = it->second;
  if (!e.writable) return ac::kReadOnly;
  if (e.size == 0) {  // a string
    if (data.size() > kMaxString) return ac::kLengthHigh;
    e.value = data;
    writes_.emplace_back(index_of(key), sub_of(key));
    return 0;
  }
  if (data.size() > e.size) return ac::kLengthHigh;
  if (data.size() < e.size) return ac::kLengthLow;
  Entry probe = e;
  probe.value = data;
  const std::int64_t v = integer(probe);
  if (v < e.min) return ac::kValueLow;
  if (v > e.max) return ac::kValueHigh;
  const std::uint16_t index = index_of(key);
  const std::uint8_t sub = sub_of(key);
  if (index == obj::kModesOfOperation && v != obj::kProfilePosition)
    return ac::kValueRange;  // profile position only
  if (index == obj::kProfileVelocity && v > u32(obj::kMaxProfileVelocity)) return ac::kValueHigh;
  if (index == obj::kRpdo1Map || index == obj::kTpdo1Map || index == obj::kTpdo2Map) {
    if (nmt_ == Nmt::Operational) return ac::kDeviceState;
    const std::uint16_t comm = static_cast<std::uint16_t>(index - 0x200);  // 0x1A0n -> 0x180n
    if ((u32(comm, 1) & 0x80000000u) == 0) return ac::kUnsupportedAccess;  // PDO valid
    auto mappable = [&](std::uint32_t entry) {
      const auto o = od_.find(entry >> 8 & 0xFFFFFF);
      if (o == od_.end() || !o->second.mappable) return false;
      if (o->second.size * 8u != (entry & 0xFF)) return false;
      return index == obj::kRpdo1Map ? o->second.writable : true;
    };
    if (sub == 0) {
      std::uint32_t bits = 0;
      for (std::uint8_t i = 1; i <= v; ++i) {
        const std::uint32_t entry = u32(index, i);
        if (!mappable(entry)) return ac::kNotMappable;
        bits += entry & 0xFF;
      }
      if (bits > 64) return ac::kPdoLength;
    } else {
      if (u32(index, 0) != 0) return ac::kUnsupportedAccess;
      if (v != 0 && !mappable(static_cast<std::uint32_t>(v))) return ac::kNotMappable;
    }
  }
  e.value = data;
  writes_.emplace_back(index, sub);
  constexpr double kInf = std::numeric_limits<double>::infinity();
  if (index == obj::kProducerHeartbeat)
    next_hb_ = v > 0 && !booting_ ? t + static_cast<double>(v) / 1000.0 : kInf;
  if (index == obj::kTpdo1Comm) {
    const std::uint32_t timer = u32(obj::kTpdo1Comm, 5);
    next_tpdo_ = event_driven() && timer > 0 ? t + timer / 1000.0 : kInf;
  }
  // the drive switches its mode a little later, as real drives do
  if (index == obj::kModesOfOperation) mode_at_ = t + setup_.mode_switch_s;
  if (index == obj::kControlword) on_controlword(t, static_cast<std::uint16_t>(v), out);
  return 0;
}

void VirtualDrive402::on_sdo(double t, const can::Frame& f, std::vector<DriveFrame>& out) {
  if (f.len != 8) {
    ++counts_.malformed;
    return;
  }
  if (booting_ || nmt_ == Nmt::Stopped) return;
  const std::uint8_t b0 = f.data[0];
  const std::uint8_t ccs = b0 >> 5;
  const std::uint32_t key =
      key_of(static_cast<std::uint16_t>(get_le(f.payload(), 1, 2)), f.data[3]);
  can::Frame r = frame8(cob::kSdoTx + setup_.node_id);
  auto respond_initiate = [&](std::uint8_t cmd) {
    r.data[0] = cmd;
    r.data[1] = f.data[1];
    r.data[2] = f.data[2];
    r.data[3] = f.data[3];
  };
  const auto refused = faults_.refuse_objects.find(key);
  switch (ccs) {
    case 4:  // abort from the client
      sdo_.active = false;
      return;
    case 1: {  // initiate download
      if (refused != faults_.refuse_objects.end()) return sdo_abort(t, key, refused->second, out);
      if ((b0 & 0x02) != 0) {  // expedited
        const std::size_t n = (b0 & 0x01) != 0 ? 4 - ((b0 >> 2) & 0x03) : 4;
        const std::vector<std::uint8_t> data(f.data.begin() + 4,
                                             f.data.begin() + 4 + static_cast<std::ptrdiff_t>(n));
        if (const std::uint32_t code = write(t, key, data, out); code != 0)
          return sdo_abort(t, key, code, out);
        respond_initiate(0x60);
        answer_sdo(t, r, out);
        return;
      }
      const auto it = od_.find(key);
      if (it == od_.end()) return sdo_abort(t, key, ac::kNoObject, out);
      if (!it->second.writable) return sdo_abort(t, key, ac::kReadOnly, out);
      sdo_ = Transfer{};
      sdo_.active = true;
      sdo_.key = key;
      sdo_.size_known = (b0 & 0x01) != 0;
      sdo_.expected = sdo_.size_known ? static_cast<std::uint32_t>(get_le(f.payload(), 4, 4)) : 0;
      respond_initiate(0x60);
      answer_sdo(t, r, out);
      return;
    }
    case 0: {  // download segment
      if (!sdo_.active || sdo_.upload) return sdo_abort(t, key, ac::kCommandSpecifier, out);
      const bool toggle = (b0 & 0x10) != 0;
      if (toggle != sdo_.toggle) return sdo_abort(t, sdo_.key, ac::kToggle, out);
      const std::size_t n = 7 - ((b0 >> 1) & 0x07);
      sdo_.buf.insert(sdo_.buf.end(), f.data.begin() + 1,
                      f.data.begin() + 1 + static_cast<std::ptrdiff_t>(n));
      r.data[0] = static_cast<std::uint8_t>(0x20 | (toggle ? 0x10 : 0));
      if ((b0 & 0x01) != 0) {
        sdo_.active = false;
        if (sdo_.size_known && sdo_.buf.size() != sdo_.expected)
          return sdo_abort(t, sdo_.key, ac::kLength, out);
        if (const std::uint32_t code = write(t, sdo_.key, sdo_.buf, out); code != 0)
          return sdo_abort(t, sdo_.key, code, out);
      }
      sdo_.toggle = !sdo_.toggle;
      answer_sdo(t, r, out);
      return;
    }
    case 2: {  // initiate upload
      if (refused != faults_.refuse_objects.end()) return sdo_abort(t, key, refused->second, out);
      std::vector<std::uint8_t> data;
      if (const std::uint32_t code = read(t, key, data); code != 0)
        return sdo_abort(t, key, code, out);
      if (!data.empty() && data.size() <= 4) {
        respond_initiate(static_cast<std::uint8_t>(0x43 | ((4 - data.size()) << 2)));
        std::copy(data.begin(), data.end(), r.data.begin() + 4);
      } else {
        respond_initiate(0x41);
        put_le(r.data, 4, 4, data.size());
        sdo_ = Transfer{};
        sdo_.active = true;
        sdo_.upload = true;
        sdo_.key = key;
        sdo_.buf = std::move(data);
      }
      answer_sdo(t, r, out);
      return;
    }
    case 3: {  // upload segment
      if (!sdo_.active || !sdo_.upload) return sdo_abort(t, key, ac::kCommandSpecifier, out);
      const bool toggle = (b0 & 0x10) != 0;
      if (toggle != sdo_.toggle) return sdo_abort(t, sdo_.key, ac::kToggle, out);
      const std::size_t n = std::min<std::size_t>(7, sdo_.buf.size() - sdo_.offset);
      const bool last = sdo_.offset + n == sdo_.buf.size();
      r.data[0] = static_cast<std::uint8_t>((toggle ? 0x10 : 0) | ((7 - n) << 1) | (last ? 1 : 0));
      std::copy_n(sdo_.buf.begin() + static_cast<std::ptrdiff_t>(sdo_.offset), n,
                  r.data.begin() + 1);
      sdo_.offset += n;
      sdo_.toggle = !sdo_.toggle;
      if (last) sdo_.active = false;
      answer_sdo(t, r, out);
      return;
    }
    default:
      return sdo_abort(t, key, ac::kCommandSpecifier, out);
  }
}

// ---- PDOs ----

void VirtualDrive402::refresh(double t) {
  set(obj::kStatusword, 0, statusword());
  dither_high_ = !dither_high_;
  const std::int64_t pos = position_counts(t) + (dither_high_ ? faults_.position_dither_counts : 0);
  set(obj::kPositionActual, 0, static_cast<std::int32_t>(static_cast<std::uint32_t>(pos)));
  set(obj::kVelocityActual, 0,
      static_cast<std::int32_t>(std::clamp<double>(std::round(sense() * motion_.at(t).rate * cpr_),
                                                   -2147483648.0, 2147483647.0)));
}

bool VirtualDrive402::tpdo_valid() const {
  return (u32(obj::kTpdo1Comm, 1) & 0x80000000u) == 0 && u32(obj::kTpdo1Map, 0) > 0;
}

bool VirtualDrive402::event_driven() const {
  return u32(obj::kTpdo1Comm, 2) >= 0xFE;
}

void VirtualDrive402::unsent(const can::Frame& f) {
  if (timed_on_the_bus(f)) last_sent_sw_.reset();
}

bool VirtualDrive402::commanded_by(const can::Frame& f) const {
  if (f.extended || f.error || f.remote || f.fd) return false;
  const std::uint32_t rpdo = u32(obj::kRpdo1Comm, 1);
  return f.id == cob::kNmt || f.id == cob::kSdoRx + setup_.node_id ||
         ((rpdo & 0x80000000u) == 0 && f.id == (rpdo & 0x7FF));
}

bool still_true_late(const LateTpdo& l) {
  if (!l.at_rest || l.scripted_host || l.command_taken_t >= l.t_s) return false;
  if (l.on_sync && (l.sync_taken_t > l.t_s || (l.sync_taken_t == l.t_s && l.syncs_taken_then > 1) ||
                    l.stand_tx_waiting))
    return false;
  return l.bus_read && !l.command_waiting && !(l.on_sync && l.sync_waiting);
}

bool VirtualDrive402::owed_heartbeat(const can::Frame& f, double late_s) const {
  // CiA 301 7.2.8.3.2.2: the heartbeat, COB-ID 0x700 + node ID, one byte
  // of NMT state; 0 is the boot-up
  if (f.extended || f.id != 0x700u + setup_.node_id || f.len != 1 || f.data[0] == 0) return false;
  const std::uint32_t hb_ms = u32(obj::kProducerHeartbeat) & 0xFFFF;
  return hb_ms > 0 && late_s >= hb_ms / 1000.0;
}

bool VirtualDrive402::timed_on_the_bus(const can::Frame& f) const {
  if (f.extended) return false;
  for (const std::uint16_t comm : {obj::kTpdo1Comm, obj::kTpdo2Comm}) {
    const std::uint32_t cob = u32(comm, 1);
    if ((cob & 0x80000000u) == 0 && f.id == (cob & 0x7FF)) return true;
  }
  return false;
}

void VirtualDrive402::send_tpdo(double t, std::vector<DriveFrame>& out) {
  if (nmt_ != Nmt::Operational || booting_ || !tpdo_valid()) return;
  const bool in_fault = state_ == State::Fault || state_ == State::FaultReactionActive;
  if (in_fault && faults_.stale == StalePdo::Silent) return;
  if (in_fault && faults_.stale == StalePdo::Frozen && frozen_) {
    emit(t, *frozen_, out);
    ++counts_.tpdo;
    last_sent_sw_ = statusword();
    return;
  }
  refresh(t);
  can::Frame f;
  f.id = u32(obj::kTpdo1Comm, 1) & 0x7FF;
  const std::uint32_t n = u32(obj::kTpdo1Map, 0);
  std::size_t at = 0;
  for (std::uint8_t i = 1; i <= n; ++i) {
    const std::uint32_t entry = u32(obj::kTpdo1Map, i);
    const Entry& e = od_.at(entry >> 8 & 0xFFFFFF);
    std::copy(e.value.begin(), e.value.end(), f.data.begin() + static_cast<std::ptrdiff_t>(at));
    at += e.value.size();
  }
  f.len = static_cast<std::uint8_t>(at);
  emit(t, f, out);
  ++counts_.tpdo;
  last_sent_sw_ = statusword();
  if (!in_fault) frozen_ = f;
  // TPDO2 goes with TPDO1, after it (its identifier loses arbitration)
  const std::uint32_t cob2 = u32(obj::kTpdo2Comm, 1);
  const std::uint32_t n2 = u32(obj::kTpdo2Map, 0);
  if ((cob2 & 0x80000000u) == 0 && n2 > 0) {
    can::Frame g;
    g.id = cob2 & 0x7FF;
    std::size_t at2 = 0;
    for (std::uint8_t i = 1; i <= n2; ++i) {
      const Entry& e = od_.at(u32(obj::kTpdo2Map, i) >> 8 & 0xFFFFFF);
      std::copy(e.value.begin(), e.value.end(), g.data.begin() + static_cast<std::ptrdiff_t>(at2));
      at2 += e.value.size();
    }
    g.len = static_cast<std::uint8_t>(at2);
    emit(t, g, out);
  }
  const std::uint32_t timer = u32(obj::kTpdo1Comm, 5);
  if (event_driven() && timer > 0) next_tpdo_ = t + timer / 1000.0;
}

void VirtualDrive402::tpdo_on_change(double t, std::vector<DriveFrame>& out) {
  if (setup_.cycle_s > 0 && !in_cycle_) return;  // at the next cycle
  if (event_driven() && statusword() != last_sent_sw_) send_tpdo(t, out);
}

void VirtualDrive402::cycle(double t, std::vector<DriveFrame>& out) {
  next_cycle_ = t + setup_.cycle_s;
  // last cycle's statusword first, then this cycle's sample of RPDO1
  in_cycle_ = true;
  if (timer_due_ && event_driven())
    send_tpdo(t, out);
  else
    tpdo_on_change(t, out);
  timer_due_ = false;
  in_cycle_ = false;
  if (rpdo_buf_) {
    const can::Frame f = *rpdo_buf_;
    rpdo_buf_.reset();
    apply_rpdo(t, f, out);
  }
}

void VirtualDrive402::on_rpdo(double t, const can::Frame& f, std::vector<DriveFrame>& out) {
  if (nmt_ != Nmt::Operational) return;
  if (setup_.cycle_s > 0) {
    rpdo_buf_ = f;  // an overwrite buffer: the next cycle sees the last one
    return;
  }
  apply_rpdo(t, f, out);
}

void VirtualDrive402::apply_rpdo(double t, const can::Frame& f, std::vector<DriveFrame>& out) {
  if (nmt_ != Nmt::Operational) return;
  const std::uint32_t n = u32(obj::kRpdo1Map, 0);
  if (n == 0) return;
  std::size_t total = 0;
  for (std::uint8_t i = 1; i <= n; ++i) total += (u32(obj::kRpdo1Map, i) & 0xFF) / 8;
  if (f.len < total) {
    ++counts_.malformed;
    emcy(t, 0x8210, 0x11, out);  // PDO not processed due to length error
    return;
  }
  ++counts_.rpdo;
  std::size_t at = 0;
  std::optional<std::uint16_t> control;
  for (std::uint8_t i = 1; i <= n; ++i) {
    const std::uint32_t entry = u32(obj::kRpdo1Map, i);
    Entry& e = od_.at(entry >> 8 & 0xFFFFFF);
    std::copy_n(f.data.begin() + static_cast<std::ptrdiff_t>(at), e.size, e.value.begin());
    at += e.size;
    if (entry >> 16 == obj::kControlword) control = static_cast<std::uint16_t>(integer(e));
  }
  if (control) on_controlword(t, *control, out);
}

// ---- CiA 402 ----

void VirtualDrive402::enter(State s) {
  if (s == State::QuickStopActive && state_ != State::QuickStopActive) ++counts_.quick_stops;
  state_ = s;
}

void VirtualDrive402::stop_motion(double t, double decel_counts, Motion why) {
  buffered_.reset();
  rest_at_ = motion_.stop(t, std::max(decel_counts, 1.0) / cpr_);
  motion_kind_ = why;
  demand_ = std::llround(sense() * motion_.at(rest_at_).angle * cpr_);
}

void VirtualDrive402::coast(double t) {
  if (!moving(t)) return;
  ++counts_.coasts;
  buffered_.reset();
  rest_at_ = motion_.stop(t, setup_.coast_deceleration_rps2);
  motion_kind_ = Motion::Coast;
  demand_ = std::llround(sense() * motion_.at(rest_at_).angle * cpr_);
}

void VirtualDrive402::ramp_or_coast(double t, std::uint16_t option_index) {
  if (static_cast<std::int16_t>(u32(option_index)) == 1)
    stop_motion(t, u32(obj::kProfileDeceleration), Motion::Stop);
  else
    coast(t);
}

void VirtualDrive402::start_move(double t, std::int64_t target) {
  demand_ = target;
  const double t0 = std::max(t, motion_.rest_time());
  const double delta = sense() * static_cast<double>(target) / cpr_ - motion_.at(t0).angle;
  const double v = u32(obj::kProfileVelocity) / cpr_;
  const double a = u32(obj::kProfileAcceleration) / cpr_;
  const double d = u32(obj::kProfileDeceleration) / cpr_;
  motion_kind_ = Motion::Move;
  const double dist = std::fabs(delta);
  if (dist * cpr_ < 0.5) {  // already there
    rest_at_ = t0;
    return;
  }
  // A trapezoid with acceleration a and deceleration d: peak w (the
  // profile velocity, or lower when the move is too short to reach it),
  // decelerating from t_dec. TableMotion plans symmetric moves, so the
  // move is planned at a past the target and cut at t_dec by a stop at d.
  double w = v;
  if (dist < v * v / (2 * a) + v * v / (2 * d)) w = std::sqrt(2 * dist * a * d / (a + d));
  const double sign = delta < 0 ? -1.0 : 1.0;
  motion_.move_by(t0, sign * (dist + w * w / (2 * a)), w, a);
  const double cruise = std::max(0.0, (dist - w * w / (2 * a) - w * w / (2 * d)) / w);
  rest_at_ = motion_.stop(t0 + w / a + cruise, d);
}

void VirtualDrive402::take_set_point(double t, std::uint16_t c) {
  if (faults_.refuse_moves || set_point_ack_ || enable_ack_) return;
  const auto target = static_cast<std::int32_t>(u32(obj::kTargetPosition));
  const bool relative = (c & facts::cw::kRelative) != 0;
  const bool in_motion = motion_kind_ == Motion::Move && t < rest_at_;
  // 0x60F2 bits 0-1 (CiA 402-2): 00 from the last target (also after a
  // halt or a quick stop), 01 from the position demand value (the
  // trajectory's own position while it moves, where it holds at rest), 10
  // from position actual; 11 is reserved (taken as 00)
  const std::uint32_t rel = u32(obj::kPositioningOption) & 0x3;
  const std::int64_t base = rel == 1   ? (in_motion ? position_counts(t) : demand_)
                            : rel == 2 ? position_counts(t)
                                       : last_target_;
  const std::int64_t abs = relative ? base + target : target;
  last_target_ = abs;
  set_point_ack_ = true;
  target_reached_ = false;
  ++counts_.set_points;
  if (!std::isnan(faults_.warning_after_move_s)) {  // armed by this move, once
    faults_.warning_at_s = t + faults_.warning_after_move_s;
    faults_.warning_after_move_s = NAN;
  }
  if (in_motion && (c & facts::cw::kChangeImmediately) == 0) {
    buffered_ = SetPoint{abs};
    return;
  }
  if (in_motion || (motion_kind_ != Motion::Rest && t < rest_at_))
    stop_motion(t, u32(obj::kProfileDeceleration), Motion::Stop);
  start_move(t, abs);
}

void VirtualDrive402::on_controlword(double t, std::uint16_t c, std::vector<DriveFrame>& out) {
  namespace cw = facts::cw;
  const std::uint16_t prev = cw_;
  cw_ = c;
  set(obj::kControlword, 0, c);
  using C = facts::Command;
  // Bit 7's edge resets a fault; outside Fault this drive reads the word's
  // other bits as usual, bit 7 high or not, as many drives do (0x0080 is
  // then Disable voltage).
  constexpr auto kOthers = static_cast<std::uint16_t>(~cw::kFaultReset);
  const facts::Command cmd = state_ == State::Fault
                                 ? facts::command_of(c, prev)
                                 : facts::command_of(c & kOthers, prev & kOthers);
  const State before = state_;
  const std::uint32_t quick = u32(obj::kQuickStopDeceleration);
  switch (state_) {
    case State::SwitchOnDisabled:
      if (cmd == C::Shutdown) enter(State::ReadyToSwitchOn);  // 2
      break;
    case State::ReadyToSwitchOn:
      if (cmd == C::SwitchOn) enter(State::SwitchedOn);                                     // 3
      if (cmd == C::EnableOperation) enter(State::OperationEnabled);                        // 3 + 4
      if (cmd == C::DisableVoltage || cmd == C::QuickStop) enter(State::SwitchOnDisabled);  // 7
      break;
    case State::SwitchedOn:
      if (cmd == C::EnableOperation) enter(State::OperationEnabled);                        // 4
      if (cmd == C::Shutdown) enter(State::ReadyToSwitchOn);                                // 6
      if (cmd == C::DisableVoltage || cmd == C::QuickStop) enter(State::SwitchOnDisabled);  // 10
      break;
    case State::OperationEnabled:
      if (cmd == C::SwitchOn) {  // 5: disable operation, per 0x605C
        ramp_or_coast(t, obj::kDisableOperationOption);
        enter(State::SwitchedOn);
      } else if (cmd == C::Shutdown) {  // 8, per 0x605B
        ramp_or_coast(t, obj::kShutdownOption);
        enter(State::ReadyToSwitchOn);
      } else if (cmd == C::DisableVoltage) {  // 9: the power stage lets go
        coast(t);
        enter(State::SwitchOnDisabled);
      } else if (cmd == C::QuickStop) {  // 11
        const auto option = static_cast<std::int16_t>(u32(obj::kQuickStopOption));
        set_point_ack_ = false;
        if (option == 0) {  // disable drive function
          coast(t);
          enter(State::SwitchOnDisabled);
        } else {
          const bool slow = option == 1 || option == 5;
          stop_motion(t, slow ? u32(obj::kProfileDeceleration) : quick, Motion::QuickStop);
          enter(State::QuickStopActive);
        }
      }
      break;
    case State::QuickStopActive:
      if (cmd == C::DisableVoltage) {  // 12: still braking, it coasts from here
        coast(t);
        enter(State::SwitchOnDisabled);
      }
      if (cmd == C::EnableOperation && u32(obj::kQuickStopOption) >= 5 && t >= rest_at_)
        enter(State::OperationEnabled);  // 16
      break;
    case State::Fault:
      if (cmd == C::FaultReset && faults_.resets_ignored > 0) {
        --faults_.resets_ignored;
      } else if (cmd == C::FaultReset) {  // 15
        enter(State::SwitchOnDisabled);
        following_error_ = false;
        set(obj::kErrorCode, 0, 0);
        ++counts_.fault_resets;
        emcy(t, 0x0000, 0, out);
      }
      break;
    default:
      break;
  }
  if (state_ != State::OperationEnabled) {
    enable_ack_ = false;
    enable_ack_until_ = std::numeric_limits<double>::infinity();
    return;
  }
  if (before != State::OperationEnabled) {
    demand_ = position_counts(t);
    target_reached_ = true;
    set_point_ack_ = false;
    if (setup_.set_point_ack_after_enable_s > 0) {
      enable_ack_ = true;
      enable_ack_until_ = t + setup_.set_point_ack_after_enable_s;
    }
  }
  if (static_cast<std::int8_t>(u32(obj::kModesDisplay)) != obj::kProfilePosition)
    return;  // profile position only, once switched
  const bool halt = (c & cw::kHalt) != 0;
  if (halt && (prev & cw::kHalt) == 0) stop_motion(t, u32(obj::kProfileDeceleration), Motion::Halt);
  if ((c & cw::kNewSetPoint) != 0 && (prev & cw::kNewSetPoint) == 0 && !halt) take_set_point(t, c);
  if ((c & cw::kNewSetPoint) == 0) set_point_ack_ = false;
}

void VirtualDrive402::fault(double t, std::uint16_t code, std::vector<DriveFrame>& out) {
  if (state_ == State::Fault || state_ == State::FaultReactionActive) return;
  emcy(t, code, static_cast<std::uint8_t>(code == 0x8130 ? 0x11 : 0x01), out);
  set_point_ack_ = false;
  enter(State::FaultReactionActive);
  stop_motion(t, u32(obj::kQuickStopDeceleration), Motion::FaultStop);
}

void VirtualDrive402::host_heartbeat_lost(double t, std::vector<DriveFrame>& out) {
  ++counts_.host_heartbeat_lost;
  host_last_hb_ = NAN;  // watched again from the next heartbeat
  if (faults_.ignores_lost_host) return emcy(t, 0x8130, 0x11, out);
  const auto option = static_cast<std::int16_t>(u32(obj::kAbortConnectionOption));
  if (option == 1) return fault(t, 0x8130, out);
  emcy(t, 0x8130, 0x11, out);
  if (option == 2 && (state_ == State::ReadyToSwitchOn || state_ == State::SwitchedOn ||
                      state_ == State::OperationEnabled || state_ == State::QuickStopActive)) {
    coast(t);  // disable voltage
    enter(State::SwitchOnDisabled);
  } else if (option == 3 && state_ == State::OperationEnabled) {
    // the quick stop command, as from the controlword
    const std::uint16_t c = cw_ & static_cast<std::uint16_t>(~facts::cw::kQuickStop);
    on_controlword(t, c, out);
  }
}

void VirtualDrive402::at_rest(double t, std::vector<DriveFrame>& out) {
  (void)out;
  const Motion kind = motion_kind_;
  motion_kind_ = Motion::Rest;
  switch (kind) {
    case Motion::Move:
      if (buffered_) {
        const std::int64_t next = buffered_->target;
        buffered_.reset();
        start_move(t, next);
      } else {
        target_reached_ = true;
      }
      break;
    case Motion::Halt:
      target_reached_ = true;
      break;
    case Motion::QuickStop: {
      target_reached_ = true;
      const auto option = static_cast<std::int16_t>(u32(obj::kQuickStopOption));
      if (state_ == State::QuickStopActive && option >= 1 && option <= 4)
        enter(State::SwitchOnDisabled);
      break;
    }
    case Motion::FaultStop:
      if (state_ == State::FaultReactionActive) enter(State::Fault);  // 14
      break;
    case Motion::Stop:
    case Motion::Coast:
    case Motion::Rest:
      break;
  }
}

}  // namespace turncal::stand
