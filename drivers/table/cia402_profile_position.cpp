// Profile position (CiA 402, 0x6060 = 1): the master's mode of operation for
// a stand's moves. A move's rate is the profile velocity (0x6081, written by
// SDO when it differs from what the drive holds), its target the target
// position (0x607A) in RPDO1, and the set-point handshake is controlword
// bit 4 (new set-point) held until statusword bit 12 (set-point
// acknowledge), then bit 10 (target reached) ends the move. Every target is
// absolute (controlword bit 6 low): a relative move's is computed here from
// the position the master tracks, so nothing depends on 0x60F2, which CiA
// 402 makes optional and whose default differs between drives. Where the
// drive has it, it is read and left as it is, unless it would move the
// table otherwise than planned (bits 4-7).
#include <cmath>
#include <limits>
#include <memory>
#include <optional>

#include "cia402_detail.hpp"
#include "turncal/drivers/cia402.hpp"

namespace turncal::cia402 {

using canopen::get_le;
using canopen::le_bytes;
using detail::hex;
using detail::kRadToDeg;
using detail::num;
using detail::to_u32_counts;

namespace {

/// 0x60F2 (positioning option code, CiA 402-2 6.2.x), its bits:
///   1-0  relative option: how a relative target counts (00 from the last
///        target, 01 from the position demand value, 10 from position
///        actual); unused here, every target being absolute
///   3-2  change immediately option: what a set-point during a move does
///        without controlword bit 5; unused (no set-point during a move
///        without bit 5)
///   5-4  request-response option: 00 is the handshake of bits 4 and 12
///        the master follows; others change it
///   7-6  rotary axis direction option: 00 positions as a linear axis;
///        01 negative only, 10 positive only, 11 the shortest way would
///        turn the table by other angles or ways than the plan's
///   15-8 reserved and manufacturer-specific
constexpr std::uint32_t kPositioningOptionsUsed = 0x00F0;

class ProfilePosition final : public OperationMode {
 public:
  ProfilePosition(const MasterSettings& s, ModeHost& host)
      : s_(s),
        host_(host),
        cpr_(s.counts_per_rad()),
        sense_(s.counts_clockwise ? -1.0 : 1.0),
        configured_velocity_(configured_velocity(s, cpr_)) {}

  [[nodiscard]] std::int8_t code() const override { return 1; }
  [[nodiscard]] const char* name() const override { return "profile position"; }

  void configuration(std::vector<ConfigWrite>& writes) const override {
    // (counted by the master's start-up budget whatever the settings; sent
    // only when they pass MasterSettings::check(), which proves it fits)
    writes.push_back({obj::kProfileVelocity, 0, le_bytes(configured_velocity_.value_or(0), 4)});
  }

  void configured() override { velocity_written_ = configured_velocity_.value_or(0); }

  [[nodiscard]] std::vector<ConfigCheck> checks() const override {
    // 0x60F2 is optional (CiA 402-2): a drive without it positions as the
    // standard's defaults say (a linear axis, the handshake of bits 4 and
    // 12); one with it is read, never written
    return {{obj::kPositioningOption, 0,
             [](const canopen::SdoResult& r) -> std::string {
               if (!r.ok()) return {};  // absent: the master was told, and goes on
               // (an expedited upload without its size says 4 bytes)
               if (r.data.empty() || r.data.size() > 4)
                 return "positioning option code (0x60F2) reads " + std::to_string(r.data.size()) +
                        " bytes, not 2";
               const std::uint32_t v = get_le(r.data, 0, r.data.size());
               if ((v & kPositioningOptionsUsed) != 0)
                 return "positioning option code (0x60F2) reads " + hex(v, 4) +
                        ": bits 4-5 (request-response option) and 6-7 (rotary axis direction "
                        "option) must be 0, a linear axis with the handshake of bits 4 and 12; "
                        "with others the table would not turn as planned: set them to 0 in the "
                        "drive";
               return {};
             },
             true}};
  }

  [[nodiscard]] std::uint16_t error_bits() const override { return sw::kFollowingError; }
  [[nodiscard]] const char* error_name() const override { return "following error"; }

  void reset() override {
    step_ = Step::None;
    reached_.reset();
  }

  void left_enabled() override {
    if (step_ == Step::Sent || step_ == Step::Acked || step_ == Step::Halting) step_ = Step::None;
    reached_.reset();
  }

  [[nodiscard]] bool moving() const override {
    return step_ == Step::WaitSdo || step_ == Step::Ready || step_ == Step::Sent ||
           step_ == Step::Acked || step_ == Step::Halting;
  }

  Status move(TableCommandCode code, std::uint8_t seq, double target_rad, double rate_rps,
              double now_s, std::vector<can::Frame>& out) override;

  void halt() override {
    step_ = Step::Halting;
    reached_.reset();  // where it stops is the table's, not a target's
  }

  ModeProgress on_status(std::uint16_t word, std::uint64_t sw_seq, bool fresh_after_halt,
                         double now_s, bool timeouts) override {
    ModeProgress p;
    // A set-point waits for bit 12 low before its bit 4 goes up (CiA 402's
    // handshake); a drive that keeps bit 12 up with no set-point of ours
    // would hold it forever: as long as a set-point may take to be taken
    // (timed from the first statusword that shows it so)
    if (step_ != Step::Ready || (word & sw::kSetPointAcknowledge) == 0) {
      ready_since_.reset();
    } else if (!ready_since_) {
      ready_since_ = now_s;
    } else if (timeouts && now_s - *ready_since_ > s_.set_point_timeout_s) {
      step_ = Step::None;
      ready_since_.reset();
      p.fault =
          "set-point not sent: the drive's statusword bit 12 (set-point acknowledge) stayed "
          "up for " +
          num(s_.set_point_timeout_s) + " s with no set-point of ours to acknowledge";
      return p;
    }
    if (step_ == Step::Sent && sw_seq > sent_seq_ && (word & sw::kSetPointAcknowledge) != 0) {
      p.acked = pending_.seq;
      step_ = Step::Acked;  // bit 4 drops with the next controlword
    } else if (timeouts && step_ == Step::Sent && now_s - sent_t_ > s_.set_point_timeout_s) {
      step_ = Step::None;
      p.fault = "set-point not acknowledged (statusword bit 12) within " +
                num(s_.set_point_timeout_s) + " s";
    } else if (step_ == Step::Acked && (word & sw::kSetPointAcknowledge) == 0 &&
               (word & sw::kTargetReached) != 0) {
      step_ = Step::Done;
      reached_ = pending_.target;
    } else if (step_ == Step::Halting && fresh_after_halt && (word & sw::kTargetReached) != 0) {
      step_ = Step::Done;
    }
    return p;
  }

  [[nodiscard]] std::uint16_t controlword_bits() const override { return flags_; }

  [[nodiscard]] std::uint16_t set_point_bits(std::uint16_t word, bool& starts) const override {
    starts = false;
    if (step_ == Step::Ready && (word & sw::kSetPointAcknowledge) == 0) {
      starts = true;
      return cw::kNewSetPoint;
    }
    // CiA 402: bit 4 stays high until the drive acknowledges (bit 12)
    return step_ == Step::Sent ? cw::kNewSetPoint : 0;
  }

  [[nodiscard]] std::int32_t set_point_target() const override { return pending_.target; }

  void set_point_sent(std::uint64_t sw_seq, double now_s) override {
    step_ = Step::Sent;
    sent_seq_ = sw_seq;
    sent_t_ = now_s;
  }

  [[nodiscard]] TableState enabled_state() const override {
    switch (step_) {
      case Step::Acked:
      case Step::Halting:
        return TableState::Moving;
      case Step::Done:
        return TableState::InPosition;
      default:
        return TableState::Holding;
    }
  }

  void held(double from_s, double to_s) override {
    if (step_ == Step::Sent && to_s > from_s)
      sent_t_ += std::max(0.0, to_s - std::max(from_s, sent_t_));
    if (ready_since_ && to_s > from_s)
      *ready_since_ += std::max(0.0, to_s - std::max(from_s, *ready_since_));
  }

 private:
  enum class Step : std::uint8_t {
    None,     ///< no move since enable
    WaitSdo,  ///< the profile velocity is being written
    Ready,    ///< the set-point goes out with the next controlword
    Sent,     ///< bit 4 set, waiting for bit 12
    Acked,    ///< bit 4 cleared, moving until bit 10
    Halting,  ///< halt set, decelerating until bit 10
    Done,     ///< target reached (or halted at rest)
  };
  struct Pending {
    std::uint8_t seq = 0;
    std::int32_t target = 0;
  };

  /// The settings' profile velocity in counts; empty when it does not fit
  /// (settings that fail check(): the master configures nothing then).
  [[nodiscard]] static std::optional<std::uint32_t> configured_velocity(const MasterSettings& s,
                                                                        double cpr) {
    auto c = to_u32_counts(s.profile_velocity_rps * kRadToDeg, cpr / kRadToDeg, "v",
                           obj::kProfileVelocity, "deg");
    if (!c) return std::nullopt;
    return *c;
  }

  const MasterSettings& s_;
  ModeHost& host_;
  double cpr_;    // counts per table rad
  double sense_;  // -1 when the drive counts clockwise
  Step step_ = Step::None;
  Pending pending_;
  std::uint64_t sent_seq_ = 0;  // statuswords received when bit 4 went out
  double sent_t_ = 0;
  std::optional<double> ready_since_;    // the first status seen with a set-point Ready
  std::optional<std::int32_t> reached_;  // the target the last move reached, not halted since
  std::uint16_t flags_ = 0;              // change immediately
  std::optional<std::uint32_t> configured_velocity_;
  std::uint32_t velocity_written_ = 0;
  std::uint64_t generation_ = 0;  // of the profile velocity's write
};

Status ProfilePosition::move(TableCommandCode code, std::uint8_t seq, double target_rad,
                             double rate_rps, double now_s, std::vector<can::Frame>& out) {
  const bool relative = code == TableCommandCode::MoveRelative;
  if (!(std::isfinite(rate_rps) && rate_rps > 0))
    return make_error("move rate " + num(rate_rps) + " rad/s must be positive");
  TURNCAL_ASSIGN(vel, to_u32_counts(rate_rps * kRadToDeg, cpr_ / kRadToDeg, "move rate",
                                    obj::kProfileVelocity, "deg/s"));
  const double c = std::round(sense_ * target_rad * cpr_);
  const double lo = std::numeric_limits<std::int32_t>::min();
  const double hi = std::numeric_limits<std::int32_t>::max();
  const char* what = relative ? "move by" : "move to";
  if (!(c >= lo && c <= hi))
    return make_error(std::string(what) + " " + num(target_rad * kRadToDeg) + " deg is " + num(c) +
                      " counts, beyond the drive's 32-bit target position (" +
                      hex(obj::kTargetPosition, 4) + ")");
  // Every target absolute. The base of a relative move: the target of the move under way
  // (change set immediately), or the target the last move reached (as a
  // drive's 0x60F2 = 01 counts, from the position demand value: no
  // settling residue carried from turn to turn), or, after a halt, a quick
  // stop or anything else, the position the master tracks.
  const auto at = host_.position_counts();
  double target = c;
  if (relative && at) {
    const double base = step_ == Step::Acked ? static_cast<double>(pending_.target)
                        : reached_           ? static_cast<double>(*reached_)
                                             : static_cast<double>(*at);
    target = base + c;
    if (!(target >= lo && target <= hi))
      return make_error("move by " + num(target_rad * kRadToDeg) + " deg ends at " + num(target) +
                        " counts, beyond the drive's 32-bit position");
  }
  if (std::string why = host_.why_no_move(); !why.empty()) return make_error(std::move(why));
  if (step_ == Step::Sent)
    return make_error("the last set-point is not yet acknowledged by the drive");
  if ((step_ == Step::Acked || step_ == Step::Halting) && !s_.change_set_immediately)
    return make_error("a move is under way (change set immediately is off)");
  if (relative && !at)
    return make_error("move by " + num(target_rad * kRadToDeg) +
                      " deg: the table's position is not known yet (no TPDO1 since the start)");
  pending_ = {seq, static_cast<std::int32_t>(target)};
  reached_.reset();  // until this one is
  flags_ = static_cast<std::uint16_t>(s_.change_set_immediately ? cw::kChangeImmediately : 0);
  if (vel == velocity_written_) {
    step_ = Step::Ready;
    return Ok{};
  }
  step_ = Step::WaitSdo;
  const std::uint64_t gen = ++generation_;
  canopen::SdoClient& sdo = host_.mode_sdo();
  sdo.download(obj::kProfileVelocity, 0, le_bytes(vel, 4),
               [this, gen, vel](const canopen::SdoResult& r) {
                 // what the drive holds, whether the move still waits or not
                 if (r.ok()) velocity_written_ = vel;
                 if (gen != generation_ || step_ != Step::WaitSdo) return;
                 if (r.ok()) {
                   step_ = Step::Ready;
                 } else {
                   step_ = Step::None;
                   host_.mode_fault(FaultCode::Sdo,
                                    "SDO abort writing the profile velocity: " + r.describe());
                 }
               });
  sdo.tick(now_s, out);
  return Ok{};
}

}  // namespace

std::unique_ptr<OperationMode> make_profile_position(const MasterSettings& s, ModeHost& host) {
  return std::make_unique<ProfilePosition>(s, host);
}

}  // namespace turncal::cia402
