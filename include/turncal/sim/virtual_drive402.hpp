// The virtual stand's CiA 402 servo drive on CANopen: a node with an
// object dictionary (SDO server, expedited and segmented, with the
// standard's abort codes), NMT (boot-up after a reset, pre-operational,
// operational, stopped), RPDO1 and TPDO1 with the default or an SDO-written
// mapping, the CiA 402 state machine driven by the controlword, profile
// position moves (a trapezoid at 0x6081/0x6083/0x6084, the set-point
// handshake, target reached, relative or absolute), quick stop (0x6085,
// then per 0x605A), halt, its heartbeat (0x1017) and its watch of the
// host's (0x1016, the action of 0x6007 and EMCY 0x8130 when it is lost),
// EMCY on faults, TPDO1 on change and event timer or on SYNC (TPDO2, for
// velocity actual when a master maps it, goes with TPDO1), a writable
// string 0x2001 (a label, up to 64 bytes) for segmented downloads; and faults
// to inject. Pure and deterministic, in the stand's time (seconds), like
// VirtualTable: advance(t) emits what is due, receive(t, frame) answers.
//
// Emulation choices where CiA 402 leaves room or the stand needs less:
// * a set-point while moving with "change set immediately" brakes at the
//   profile deceleration and then sets off to the new target (a real drive
//   blends); without it the set-point waits for the move under way;
// * a relative target counts per 0x60F2 bits 0-1 (CiA 402-2): 00 (the
//   default, as on many drives) from the last target, 01 from the position
//   demand value, 10 from position actual;
// * 0x6061 shows a mode written to 0x6060 mode_switch_s later; until then
//   set-points are ignored;
// * releasing halt does not resume the move: a new set-point is needed;
// * disable voltage, shutdown and disable operation while moving stop at
//   the quick stop deceleration (a motor let go would coast);
// * a lost host heartbeat does not change the NMT state (0x1029 absent);
// * an event-driven TPDO1 goes on every statusword change and at its event
//   timer (position changes alone wait for the timer).
//
// Written from CiA 301 and CiA 402 alone (cia_facts.hpp): it includes
// none of the master's code, so the master's assumptions are its to
// contradict.
#pragma once

#include <cmath>
#include <cstdint>
#include <deque>
#include <limits>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "turncal/can/frame.hpp"
#include "turncal/physics/profile.hpp"
#include "turncal/sim/cia_facts.hpp"

namespace turncal::stand {

struct Drive402Setup {
  std::uint8_t node_id = 1;
  double counts_per_rev = 131072;  ///< encoder counts per motor revolution
  double gear_ratio = 1;           ///< motor turns per table turn
  /// Counts rise clockwise seen from above; the table angle (angle(),
  /// motion()) is counter-clockwise whatever the counts do.
  bool counts_clockwise = false;
  double angle0_rad = 0;        ///< table angle at power-on
  double power_on_s = 0;        ///< the boot-up message comes boot_delay_s later
  double boot_delay_s = 0.005;  ///< from a reset to the boot-up message
  std::string device_name = "turncal virtual CiA 402 drive";  ///< 0x1008
  std::uint32_t max_profile_velocity = 0x7FFFFFFF;            ///< 0x607F, counts/s
  /// RPDO1 and TPDO1 mapped as CiA 402's defaults after a reset; false:
  /// no objects mapped until the master writes a mapping.
  bool default_mapping = true;
  std::uint16_t tpdo_event_timer_ms = 10;      ///< 0x1800:05 after a reset
  std::uint8_t tpdo_transmission_type = 0xFF;  ///< 0x1800:02 after a reset
  std::uint16_t producer_heartbeat_ms = 0;     ///< 0x1017 after a reset
  /// > 0: the drive works in cycles of this length, as a real one does:
  /// RPDO1 is an overwrite buffer sampled once a cycle (a controlword
  /// overwritten before the cycle is never seen), and the statusword that
  /// answers goes out with the next cycle's TPDO1. 0: every frame is taken
  /// at once and answered at once.
  double cycle_s = 0;
  /// Delay of a write of 0x6060 before 0x6061 shows it and the mode works
  /// (a set-point before then is ignored).
  double mode_switch_s = 0.003;
  /// 0x60F2 after a reset; bits 0-1 = 00 (the default of many drives): a
  /// relative target counts from the last target; 01: from the position
  /// demand value; 10: from position actual.
  std::uint16_t positioning_option = 0;
  /// With its power stage off (Disable voltage, or an option code of 0 on
  /// shutdown, disable operation or quick stop) the drive no longer brakes:
  /// the table runs down on its bearings' friction alone, this slowly.
  double coast_deceleration_rps2 = 0.0349;  // 2 deg/s^2
  /// Statusword bit 10 (target reached) in quick stop active once at rest,
  /// as many drives set it; false: never there (CiA 402 defines it for the
  /// profile modes' operation enabled; a drive need not set it elsewhere).
  bool target_reached_in_quick_stop = true;
  /// > 0: statusword bit 12 (set-point acknowledge) up this long after each
  /// entry into operation enabled, with no set-point (a drive whose
  /// trajectory generator is busy starting up); a set-point's bit 4 in that
  /// time is not taken. Infinity: it never drops.
  double set_point_ack_after_enable_s = 0;
  /// Each SDO answer this long after its request, spread over [min, max]
  /// (a drive whose SDO server runs in its slow task: 2 to 5 ms are
  /// common); 0: at once.
  double sdo_answer_min_s = 0;
  double sdo_answer_max_s = 0;
  /// Not 0: an EMCY of this code (one that warns, statusword bit 7 for as
  /// long as it lasts) right after each boot-up, cleared by an EMCY 0x0000
  /// once it is operational (a drive that reports its DC link charging, or
  /// the CAN controller's error passive while the bus came up).
  std::uint16_t boot_warning_code = 0;
  /// Statusword bit 5 (quick stop) set where CiA 402's table 30 leaves it
  /// free (not ready to switch on, switch on disabled, fault reaction
  /// active, fault: 0x0260 and 0x0228 rather than 0x0240 and 0x0208), as
  /// many drives send it.
  bool quick_stop_bit_where_free = false;
};

/// What TPDO1 does while the drive is in fault (the stale-PDO trap).
enum class StalePdo : std::uint8_t {
  None,    ///< TPDO1 as usual: the statusword shows the fault
  Silent,  ///< no TPDO1 while in fault reaction or fault
  Frozen,  ///< the last TPDO1 from before the fault, repeated
};

/// Faults to inject, each once.
struct Drive402Faults {
  double fault_at_s = NAN;  ///< a drive fault with EMCY fault_code
  std::uint16_t fault_code = 0x2310;
  /// The injected fault's state this long after its EMCY (a drive whose
  /// EMCY goes out from its fast task, its statusword from a slower one).
  double fault_state_after_emcy_s = 0;
  StalePdo stale = StalePdo::None;
  double silent_at_s = NAN;  ///< the drive neither sends nor hears anything from then ...
  double silent_until_s = std::numeric_limits<double>::infinity();  ///< ... to then
  double following_error_at_s = NAN;  ///< statusword bit 13, EMCY 0x8611, fault
  /// An EMCY that only warns (statusword bit 7): the drive keeps moving.
  double warning_at_s = NAN;
  std::uint16_t warning_code = 0x4210;  ///< excess temperature device
  /// The same warning this long after the first set-point taken: inside a
  /// move, wherever the run's schedule puts it.
  double warning_after_move_s = NAN;
  bool refuse_moves = false;  ///< new set-points are never acknowledged
  int resets_ignored = 0;     ///< the first fault resets leave it in fault (the cause persists)
  /// Its position actual dithers by this many counts, every other refresh
  /// (an encoder at rest on the edge of a count).
  int position_dither_counts = 0;
  /// It counts a lost host but takes no action, whatever 0x6007 says (a
  /// drive whose firmware does not act on the object).
  bool ignores_lost_host = false;
  /// (index << 8 | sub) -> abort code for any SDO access to that object.
  std::map<std::uint32_t, std::uint32_t> refuse_objects;
};

struct DriveFrame {
  double t_s;
  can::Frame frame;
};

struct Drive402Counts {
  std::uint64_t nmt_resets = 0;  ///< reset communication or node
  std::uint64_t sdo_aborts = 0;  ///< sent by the drive
  std::uint64_t rpdo = 0;
  std::uint64_t tpdo = 0;
  std::uint64_t sync = 0;
  std::uint64_t malformed = 0;  ///< frames of ours of a wrong length: counted, skipped
  std::uint64_t host_heartbeats = 0;
  std::uint64_t host_heartbeat_lost = 0;
  std::uint64_t quick_stops = 0;  ///< entries into quick stop active
  std::uint64_t set_points = 0;   ///< acknowledged
  std::uint64_t fault_resets = 0;
  /// Power stage switched off while the table turned: it coasts.
  std::uint64_t coasts = 0;
};

class VirtualDrive402 {
 public:
  explicit VirtualDrive402(const Drive402Setup& setup = {}, const Drive402Faults& faults = {});

  /// Runs the drive's own events up to t (boot-up, heartbeat, the host
  /// heartbeat watch, motion ending, TPDO event timer, injected faults) and
  /// emits their frames. Non-decreasing t.
  void advance(double t, std::vector<DriveFrame>& out);
  /// A frame from the bus at t (after advance(t)); answers go to `out`.
  void receive(double t, const can::Frame& f, std::vector<DriveFrame>& out);

  [[nodiscard]] facts::State state() const { return state_; }
  [[nodiscard]] std::uint16_t statusword() const;
  [[nodiscard]] std::uint16_t controlword() const { return cw_; }
  [[nodiscard]] facts::Nmt nmt() const { return nmt_; }
  [[nodiscard]] bool booted() const { return !booting_; }
  /// True multi-turn table angle, rad, and the motion the INS turns by.
  [[nodiscard]] double angle(double t) const { return motion_.at(t).angle; }
  [[nodiscard]] double rate(double t) const { return motion_.at(t).rate; }
  [[nodiscard]] const TableMotion& motion() const { return motion_; }
  /// Position actual, counts (not wrapped to s32).
  [[nodiscard]] std::int64_t position_counts(double t) const;
  [[nodiscard]] bool moving(double t) const { return t < rest_at_; }
  /// An object's value as an integer (signed where its type is), if it exists.
  [[nodiscard]] std::optional<std::int64_t> value(std::uint16_t index, std::uint8_t sub) const;
  /// Successful SDO writes, in order: (index, sub).
  [[nodiscard]] const std::vector<std::pair<std::uint16_t, std::uint8_t>>& sdo_writes() const {
    return writes_;
  }
  /// EMCY codes sent, in order.
  [[nodiscard]] const std::vector<std::uint16_t>& emcy_sent() const { return emcy_sent_; }
  [[nodiscard]] const Drive402Counts& counts() const { return counts_; }
  [[nodiscard]] double counts_per_rad() const { return cpr_; }
  /// A frame of this drive's the host dates by the bus: TPDO1, or TPDO2
  /// which goes with it, by its receipt (sent on its event timer or on
  /// change) or by the SYNC it answers. A real drive samples what such a
  /// frame carries as it sends it, within its cycle of the SYNC.
  [[nodiscard]] bool timed_on_the_bus(const can::Frame& f) const;
  /// TPDO1 goes on change and on its event timer (transmission type 254,
  /// 255); else on SYNC.
  [[nodiscard]] bool event_driven() const;
  /// Such a frame was not sent after all (turncal-sim, late): as if the bus
  /// had lost it, the change it carried goes with the drive's next TPDO
  /// (event-driven: at its next chance; synchronous: the next SYNC's).
  void unsent(const can::Frame& f);
  /// A heartbeat of this drive (not its boot-up) due `late_s` stand
  /// seconds before the time the stand is catching up to, a producer period
  /// or more: the stand fell behind real time, and a later heartbeat falls
  /// due before that time, so goes out in the same catch-up (the last one
  /// due is never owed). A real drive sends its
  /// heartbeat on its own clock, never a burst of past states (after an NMT
  /// start, a master reads an old pre-operational one as the drive leaving
  /// operational): turncal-sim leaves it unsent. A boot-up is never held
  /// back.
  [[nodiscard]] bool owed_heartbeat(const can::Frame& f, double late_s) const;
  /// A frame that can change what the drive does or says: NMT, its SDO
  /// requests, its RPDO1 (not SYNC, nor the host's heartbeat it watches).
  [[nodiscard]] bool commanded_by(const can::Frame& f) const;

 private:
  struct Entry {
    std::uint8_t size = 0;  // bytes; 0: a string
    bool writable = false;
    bool mappable = false;
    bool is_signed = false;
    std::int64_t min = 0, max = 0;
    std::vector<std::uint8_t> value;
  };
  enum class Motion : std::uint8_t { Rest, Move, Halt, QuickStop, FaultStop, Stop, Coast };
  struct SetPoint {
    std::int64_t target = 0;  // absolute counts
  };

  void build_dictionary();
  void reset_communication(double t);
  void add(std::uint16_t index, std::uint8_t sub, Entry e);
  [[nodiscard]] std::uint32_t u32(std::uint16_t index, std::uint8_t sub = 0) const;
  [[nodiscard]] std::int64_t integer(const Entry& e) const;
  void set(std::uint16_t index, std::uint8_t sub, std::int64_t v);
  [[nodiscard]] bool silent(double t) const;
  void emit(double t, const can::Frame& f, std::vector<DriveFrame>& out);
  /// An SDO answer: at once, or after the setup's delay.
  void answer_sdo(double t, const can::Frame& f, std::vector<DriveFrame>& out);
  void emcy(double t, std::uint16_t code, std::uint8_t reg, std::vector<DriveFrame>& out);

  void on_nmt(double t, const can::Frame& f, std::vector<DriveFrame>& out);
  void on_sdo(double t, const can::Frame& f, std::vector<DriveFrame>& out);
  void on_rpdo(double t, const can::Frame& f, std::vector<DriveFrame>& out);
  void apply_rpdo(double t, const can::Frame& f, std::vector<DriveFrame>& out);
  void cycle(double t, std::vector<DriveFrame>& out);
  void on_sync(double t, std::vector<DriveFrame>& out);
  /// 0: written; else the abort code.
  std::uint32_t write(double t, std::uint32_t key, const std::vector<std::uint8_t>& data,
                      std::vector<DriveFrame>& out);
  std::uint32_t read(double t, std::uint32_t key, std::vector<std::uint8_t>& data);
  void sdo_abort(double t, std::uint32_t key, std::uint32_t code, std::vector<DriveFrame>& out);

  void on_controlword(double t, std::uint16_t c, std::vector<DriveFrame>& out);
  void take_set_point(double t, std::uint16_t c);
  void start_move(double t, std::int64_t target);
  void stop_motion(double t, double decel_counts, Motion why);
  /// +1, or -1 when the counts rise clockwise: counts = sense * angle * cpr.
  [[nodiscard]] double sense() const { return setup_.counts_clockwise ? -1.0 : 1.0; }
  /// The power stage off while turning: the table runs down on friction.
  void coast(double t);
  /// Stops on the profile deceleration when the option object holds 1,
  /// else coasts (0x605B, 0x605C: 0 disables the drive function at once).
  void ramp_or_coast(double t, std::uint16_t option_index);
  void fault(double t, std::uint16_t code, std::vector<DriveFrame>& out);
  void host_heartbeat_lost(double t, std::vector<DriveFrame>& out);
  void at_rest(double t, std::vector<DriveFrame>& out);
  void enter(facts::State s);

  void refresh(double t);
  [[nodiscard]] bool tpdo_valid() const;
  void send_tpdo(double t, std::vector<DriveFrame>& out);
  void tpdo_on_change(double t, std::vector<DriveFrame>& out);

  Drive402Setup setup_;
  Drive402Faults faults_;
  bool dither_high_ = false;
  double cpr_;
  std::map<std::uint32_t, Entry> od_;
  std::map<std::uint32_t, Entry> comm_defaults_;  // 0x1000..0x1FFF after a reset
  std::map<std::uint32_t, Entry> app_defaults_;   // 0x2000.. after a node reset
  double now_ = -std::numeric_limits<double>::infinity();
  // NMT
  facts::Nmt nmt_ = facts::Nmt::PreOperational;
  bool booting_ = true;
  double boot_at_ = 0;
  double next_hb_ = std::numeric_limits<double>::infinity();
  double host_last_hb_ = NAN;  // the consumer is armed by the first one
  // SDO server
  struct Transfer {
    bool active = false;
    bool upload = false;
    std::uint32_t key = 0;
    std::vector<std::uint8_t> buf;
    std::size_t offset = 0;
    std::uint32_t expected = 0;
    bool size_known = false;
    bool toggle = false;
  } sdo_;
  // CiA 402
  facts::State state_ = facts::State::SwitchOnDisabled;
  std::uint16_t cw_ = 0;
  bool target_reached_ = true;
  bool set_point_ack_ = false;
  bool enable_ack_ = false;  // bit 12 up after enable (set_point_ack_after_enable_s)
  double enable_ack_until_ = std::numeric_limits<double>::infinity();
  bool following_error_ = false;
  bool warning_ = false;
  bool boot_warning_ = false;  // warning_ is the boot-up's (boot_warning_code)
  double fault_state_at_ = std::numeric_limits<double>::infinity();  // an injected fault's state
  TableMotion motion_;
  Motion motion_kind_ = Motion::Rest;
  double rest_at_ = -std::numeric_limits<double>::infinity();
  std::int64_t demand_ = 0;  // counts the drive is headed for (or holds)
  std::optional<SetPoint> buffered_;
  // TPDO
  double next_tpdo_ = std::numeric_limits<double>::infinity();
  std::optional<std::uint16_t> last_sent_sw_;
  std::optional<can::Frame> frozen_;
  std::uint32_t sync_count_ = 0;
  // cycles
  double next_cycle_ = std::numeric_limits<double>::infinity();
  std::optional<can::Frame> rpdo_buf_;  // the RPDO1 not yet sampled
  bool in_cycle_ = false;
  bool timer_due_ = false;  // the event timer fell in this cycle
  // modes of operation: 0x6061 follows 0x6060 at mode_at_
  double mode_at_ = std::numeric_limits<double>::infinity();
  std::int64_t last_target_ = 0;  // the last set-point's absolute target, counts
  std::vector<std::pair<std::uint16_t, std::uint8_t>> writes_;
  std::deque<DriveFrame> sdo_due_;  // SDO answers not yet due
  double sdo_spread_ = 0;
  std::vector<std::uint16_t> emcy_sent_;
  Drive402Counts counts_;
};

/// What turncal-sim knows of one of the drive's TPDOs that would go out
/// late, its host having fallen behind real time. Such a frame is dated by
/// its receipt (event-driven) or by the SYNC it answers, within half a
/// period; a real drive samples what it carries as it sends it, so a late
/// one would date the position by the stall.
struct LateTpdo {
  double t_s = 0;              ///< the frame's stand time: the tick that made it
  bool at_rest = false;        ///< the table not moving at t_s
  bool on_sync = false;        ///< an answer to a SYNC (else event-driven)
  bool scripted_host = false;  ///< a script commands the drive, not a host on the bus
  /// The stand times of the last tick that took a frame commanding the
  /// drive (VirtualDrive402::commanded_by), and of the last that took a
  /// SYNC, with how many it took: a frame is answered at the tick after the
  /// one that took it, dated by that one. A frame taken in the tick a TPDO
  /// is dated by counts too: a TPDO made as the tick begins (its timer, a
  /// change) was made before it; one made in answer to a frame of that
  /// tick may have been made after, but the order is not kept, and such a
  /// TPDO refused goes with the drive's next.
  double command_taken_t = -std::numeric_limits<double>::infinity();
  double sync_taken_t = -std::numeric_limits<double>::infinity();
  int syncs_taken_then = 0;
  bool stand_tx_waiting = false;  ///< the stand's frames wait in its send queue, to go before it
  bool bus_read = false;          ///< every socket read to the end, none gone or in error
  bool command_waiting = false;   ///< a frame commanding the drive on the bus, not yet taken
  bool sync_waiting = false;      ///< a SYNC on the bus, not yet taken
};

/// Whether what a late TPDO says is as true at its receipt, so it may go
/// out late rather than not at all: the table at rest, and nothing could
/// have changed the drive since its time (no command taken since, none
/// waiting on a bus read to the end, no script); on SYNC besides, no later
/// SYNC taken or waiting and nothing of the stand's queued before it, or
/// the host would take it as a later SYNC's answer. (The drive's own timed
/// events, a fault injected or its host heartbeat's timeout, are not
/// looked ahead for: their frames follow at once, as a real drive's would
/// after a TPDO it sent just before.)
[[nodiscard]] bool still_true_late(const LateTpdo& l);

}  // namespace turncal::stand
