// A CiA 402 servo drive as the run's table ([table] protocol = "cia402"):
// the CANopen master of cia402.hpp behind the TableDriver interface.
//
// Every frame of the drive's node goes to the master (TPDOs, its SDO
// answers, heartbeat and EMCYs, whether the DBC describes them or not);
// our own frames, as a recording or a bus echo holds them (RPDO1, SDO
// requests, NMT, our heartbeat, SYNC), are recognised and left alone. A
// TPDO1 gives an encoder sample (returned by decode()) and a status sample
// (queued: pending()), so the status stream has the TPDO's rate; a status
// change from an EMCY, a heartbeat or a timeout is queued too.
//
// Observe mode (a replay, or a stand someone else drives): start() is
// never called and the master stays idle, sending nothing; the status is
// then read from the recorded statuswords and EMCYs alone.
#include <cmath>
#include <cstdio>
#include <deque>
#include <limits>
#include <numbers>
#include <optional>
#include <string>

#include "turncal/drivers/canopen.hpp"
#include "turncal/drivers/cia402.hpp"
#include "turncal/drivers/reference.hpp"

namespace turncal::drivers {

namespace {

constexpr double kDeg = std::numbers::pi / 180;

/// The master's settings from the configuration; the PDO layouts from the
/// DBC messages the roles name.
Result<cia402::MasterSettings> master_settings(const Cia402Settings& c, const RoleMap& roles,
                                               const CanConfig* where = nullptr) {
  // an error at the role's key in the configuration, when it is known
  auto at = [&](Role r, const std::string& what) {
    return make_error(
        "key 'can.roles." + std::string(role_key(r)) + "': " + what,
        where != nullptr ? where->roles[static_cast<std::size_t>(r)].where : SourcePos{});
  };
  cia402::MasterSettings s;
  s.node_id = c.node_id;
  s.host_node_id = c.host_node_id;
  s.host_heartbeat_period_s = c.host_heartbeat_period_s;
  s.host_heartbeat_timeout_s = c.host_heartbeat_timeout_s;
  s.drive_heartbeat_period_s = c.drive_heartbeat_period_s;
  s.drive_heartbeat_timeout_s = c.drive_heartbeat_timeout_s;
  s.sdo_timeout_s = c.sdo_timeout_s;
  s.boot_timeout_s = c.boot_timeout_s;
  s.counts_per_rev = c.counts_per_revolution;
  s.gear_ratio = c.gear_ratio;
  s.counts_clockwise = c.counts_clockwise;
  s.profile_acceleration_rps2 = c.profile_acceleration_rps2;
  s.profile_deceleration_rps2 = c.profile_deceleration_rps2;
  s.quick_stop_deceleration_rps2 = c.quick_stop_deceleration_rps2;
  s.quick_stop_option = c.quick_stop_option_code;
  s.abort_connection_option = c.abort_connection_option_code;
  if (c.emcy_warnings) s.emcy_warnings = *c.emcy_warnings;
  s.change_set_immediately = c.change_set_immediately;
  s.configure_mapping = c.configure_mapping;
  s.velocity_pdo = c.velocity_pdo;
  s.sync_period_s = c.sync_period_s;
  s.tpdo_event_timer_s = c.tpdo_event_timer_s;
  auto name = [&](Role r) { return std::string_view(roles[r].signal->name); };
  const auto rpdo =
      cia402::RpdoLayout::from_dbc(*roles[Role::TableControlword].message,
                                   name(Role::TableControlword), name(Role::TableTargetPosition));
  if (!rpdo)
    return at(Role::TableControlword,
              "RPDO1 with can.roles.table_target_position: " + rpdo.error().message);
  if (roles[Role::TableTargetPosition].message != roles[Role::TableControlword].message)
    return at(Role::TableTargetPosition, "must be in the controlword's message (RPDO1)");
  const auto tpdo =
      cia402::TpdoLayout::from_dbc(*roles[Role::TableStatusword].message,
                                   name(Role::TableStatusword), name(Role::TablePositionActual));
  if (!tpdo)
    return at(Role::TableStatusword,
              "TPDO1 with can.roles.table_position_actual: " + tpdo.error().message);
  if (roles[Role::TablePositionActual].message != roles[Role::TableStatusword].message)
    return at(Role::TablePositionActual, "must be in the statusword's message (TPDO1)");
  s.rpdo = *rpdo;
  s.tpdo = *tpdo;
  if (c.velocity_pdo) {
    const auto v = cia402::VelocityPdoLayout::from_dbc(*roles[Role::TableVelocityActual].message,
                                                       name(Role::TableVelocityActual));
    if (!v) return at(Role::TableVelocityActual, v.error().message);
    s.tpdo2 = *v;
  }
  TURNCAL_TRY(s.check());
  return s;
}

class Cia402Table final : public TableDriver {
 public:
  Cia402Table(cia402::MasterSettings s, std::string invalid)
      : invalid_(std::move(invalid)), master_(s), s_(master_.settings()) {}

  Decoded decode(const FrameView& v) override {
    const can::Frame& f = v.frame;
    now_ = std::max(now_, v.host_s);
    if (f.extended || f.error || f.remote || f.fd) return Decoded{};
    if (f.id == 0 && f.len == 2 && (f.data[1] == s_.node_id || f.data[1] == 0)) {
      // NMT, ours or another master's (an observer, a replay): the drive's
      // PDOs run from a start. A reset starts it up again, through
      // pre-operational (its configuration), within the master's start-up
      // budget, as the live master bounds it; a stop, or pre-operational
      // while it ran, stops its PDOs at once: the streams are due and lost.
      switch (static_cast<canopen::NmtCommand>(f.data[0])) {
        case canopen::NmtCommand::Start:
          seen_running_since_ = v.host_s;
          seen_starting_ = false;
          break;
        case canopen::NmtCommand::ResetNode:
        case canopen::NmtCommand::ResetCommunication:
          seen_running_since_ = v.host_s + master_.start_up_budget_s();
          seen_starting_ = true;
          break;
        case canopen::NmtCommand::EnterPreOperational:
          if (!seen_starting_) seen_running_since_ = v.host_s;
          break;
        case canopen::NmtCommand::Stop:
          seen_running_since_ = v.host_s;
          seen_starting_ = false;
          break;
        default:
          break;  // no command CiA 301 defines: the drive ignores it too
      }
    }
    if (ours(f.id)) {
      // a SYNC (the time of the TPDO1s that answer it) and NMT (their
      // stream starts over), as the bus had them: our echoes live, the
      // log's lines in a replay
      if (f.id == canopen::kSyncId || f.id == 0) {
        const std::uint64_t malformed = master_.counts().malformed;
        master_.on_frame(f, v.host_s, tx_);
        if (master_.counts().malformed != malformed) return Decoded::malformed();
      }
      return Decoded::taken(kStreams, NAN, std::monostate{});
    }
    if (!drives(f.id)) return Decoded{};
    const cia402::MasterCounts before = master_.counts();
    master_.on_frame(f, v.host_s, tx_);
    if (!started_) tx_.clear();  // an observer sends nothing
    const cia402::MasterCounts& after = master_.counts();
    if (after.malformed != before.malformed) return Decoded::malformed();
    if (after.emcy != before.emcy) {
      const canopen::Emcy& e = master_.emergencies().back();
      last_emcy_ = e.code != 0 ? e.text : std::string();
    }
    samples_.clear();
    master_.take_samples(samples_);
    Decoded d = Decoded::taken(kStreams, NAN, std::monostate{});
    if (!samples_.empty()) {
      const cia402::EncoderSample& e = samples_.back();
      d = Decoded::taken(kEncoder, e.t_s, EncoderSample{e.t_s, v.host_s, e.angle_rad});
      d.lost_before =
          e.lost_before == cia402::EncoderSample::kRestarted ? kStreamRestarted : e.lost_before;
    }
    // a TPDO1 is the drive's status too; anything else, when it changed it
    queue_status(v.host_s, after.tpdo != before.tpdo);
    return d;
  }

  [[nodiscard]] double angle_resolution_rad() const override { return 1 / s_.counts_per_rad(); }
  [[nodiscard]] std::string geometry() const override {
    char b[160];
    std::snprintf(b, sizeof b, "counts_per_revolution %.17g, gear_ratio %.17g, counts increase %s",
                  s_.counts_per_rev, s_.gear_ratio,
                  s_.counts_clockwise ? "clockwise" : "counter-clockwise");
    return b;
  }
  [[nodiscard]] const std::vector<std::string>& notices() const override {
    return master_.notices();
  }

  Result<std::vector<can::Frame>> command(const TableCommand& c) override {
    std::vector<can::Frame> out;
    if (!invalid_.empty()) return make_error(invalid_);
    TURNCAL_TRY(master_.command(c.code, c.seq, c.target_rad, c.rate_rps, now_, out));
    queue_status(now_, false);
    return out;
  }

  [[nodiscard]] std::vector<can::Frame> heartbeat(std::uint8_t /*counter*/,
                                                  int /*host_state*/) const override {
    // Once started, the master sends our heartbeat from tick() at its own
    // period (host_heartbeat_ms, which the drive's 0x1016 watches); before,
    // the caller's timer does. CANopen's heartbeat has no counter: the NMT
    // state of the host.
    if (started_) return {};
    return {canopen::heartbeat_frame(s_.host_node_id, canopen::NmtState::Operational)};
  }

  void set_heartbeat(bool on) override { master_.set_host_heartbeat(on); }

  [[nodiscard]] SignalSpan target() const override {
    // position actual and target position are s32 counts
    const double k = s_.counts_per_rad();
    char range[96];
    std::snprintf(range, sizeof range, "%.6g to %.6g deg (s32 counts)", -2147483648.0 / k / kDeg,
                  2147483647.0 / k / kDeg);
    return {"CiA 402 target position 0x607A", -2147483648.0 / k, 2147483647.0 / k, range};
  }
  [[nodiscard]] SignalSpan rate_limit() const override {
    // profile velocity: u32 counts/s, at least one
    const double k = s_.counts_per_rad();
    char range[96];
    std::snprintf(range, sizeof range, "%.6g to %.6g deg/s (u32 counts/s)", 1 / k / kDeg,
                  4294967295.0 / k / kDeg);
    return {"CiA 402 profile velocity 0x6081", 1 / k, 4294967295.0 / k, range};
  }

  [[nodiscard]] std::vector<std::pair<std::uint32_t, bool>> receive_ids() const override {
    const std::uint32_t n = s_.node_id;
    std::vector<std::pair<std::uint32_t, bool>> ids{{s_.tpdo_layout().cob_id, false},
                                                    {canopen::kSdoTxBase + n, false},
                                                    {canopen::kHeartbeatBase + n, false},
                                                    {canopen::kEmcyBase + n, false}};
    if (s_.velocity_pdo) ids.emplace_back(s_.velocity_layout().cob_id, false);
    return ids;
  }

  [[nodiscard]] double streams_due_s() const override {
    if (started_ && invalid_.empty()) {
      const double running = master_.running_since_s();
      return std::isnan(running) ? master_.starting_since_s() + master_.start_up_budget_s()
                                 : running;
    }
    return seen_running_since_;
  }

  void start(double now_s, std::vector<can::Frame>& out) override {
    now_ = std::max(now_, now_s);
    started_ = true;
    if (invalid_.empty()) master_.start(now_, out);
    queue_status(now_, false);
  }
  void tick(double now_s, std::vector<can::Frame>& out) override {
    now_ = std::max(now_, now_s);
    if (!started_ || !invalid_.empty()) return;
    master_.tick(now_, out);
    queue_status(now_, false);
  }
  void held(double from_s, double to_s) override {
    if (started_ && invalid_.empty()) master_.held(from_s, to_s);
  }
  void take_frames(std::vector<can::Frame>& out) override {
    out.insert(out.end(), tx_.begin(), tx_.end());
    tx_.clear();
  }
  Decoded pending() override {
    if (queue_.empty()) return Decoded{};
    Decoded d = Decoded::taken(kTableStatus, NAN, std::move(queue_.front()));
    queue_.pop_front();
    return d;
  }

 private:
  /// Our own frames: NMT, SYNC, RPDO1, SDO requests, our heartbeat.
  [[nodiscard]] bool ours(std::uint32_t id) const {
    return id == 0 || id == canopen::kEmcyBase /* SYNC */ || id == s_.rpdo_layout().cob_id ||
           id == canopen::kSdoRxBase + s_.node_id ||
           id == canopen::kHeartbeatBase + s_.host_node_id;
  }
  [[nodiscard]] bool drives(std::uint32_t id) const {
    for (const auto& [rx, ext] : receive_ids())
      if (rx == id) return true;
    return false;
  }

  /// The status the sequencer sees: the master's while it runs the drive;
  /// for an observer, what the drive's statuswords and EMCYs say.
  [[nodiscard]] TableStatusSample status(double host_s) const {
    if (started_ && !invalid_.empty())
      return {host_s,   static_cast<int>(TableState::Fault),
              0,        static_cast<int>(cia402::FaultCode::Configuration),
              invalid_, NAN};
    if (started_) {
      const cia402::TableView t = master_.status();
      return {host_s,    static_cast<int>(t.state), t.ack, static_cast<int>(t.fault), t.fault_name,
              t.rate_rps};
    }
    TableState st = TableState::Disabled;
    int fault = 0;
    std::string name;
    const std::uint16_t w = master_.statusword().value_or(0);
    switch (master_.drive_state()) {
      case cia402::State::OperationEnabled:
        st = (w & cia402::sw::kTargetReached) != 0 ? TableState::InPosition : TableState::Moving;
        break;
      case cia402::State::QuickStopActive:
        st = TableState::QuickStopped;
        break;
      case cia402::State::FaultReactionActive:
      case cia402::State::Fault:
        st = TableState::Fault;
        fault = static_cast<int>(cia402::FaultCode::DriveFault);
        name = "drive in fault (statusword)";
        break;
      default:
        break;
    }
    if (!last_emcy_.empty() && st == TableState::Fault) {
      fault = static_cast<int>(cia402::FaultCode::Emcy);
      name = last_emcy_;
    }
    const double rate = s_.velocity_pdo ? master_.velocity_rps()
                                        : master_.status().rate_rps;  // positions' otherwise
    return {host_s, static_cast<int>(st), 0, fault, name, rate};
  }

  void queue_status(double host_s, bool always) {
    TableStatusSample s = status(host_s);
    const bool changed = !last_ || last_->state != s.state || last_->ack != s.ack ||
                         last_->fault != s.fault || last_->fault_name != s.fault_name;
    if (!always && !changed) return;
    // a status of an idle observer before any statusword says nothing
    if (!started_ && !master_.statusword()) return;
    last_ = s;
    queue_.push_back(std::move(s));
  }

  std::string invalid_;  // why the settings do not fit; the master is then inert
  cia402::Master master_;
  const cia402::MasterSettings& s_;
  bool started_ = false;
  // NMT seen on the bus: when the drive was last started, NaN after a
  // reset; before any NMT, always (a drive someone else runs)
  double seen_running_since_ = -std::numeric_limits<double>::infinity();
  bool seen_starting_ = false;  ///< a reset seen, no start since
  double now_ = 0;
  std::vector<can::Frame> tx_;
  std::vector<cia402::EncoderSample> samples_;
  std::deque<TableStatusSample> queue_;
  std::optional<TableStatusSample> last_;
  std::string last_emcy_;
};

}  // namespace

std::unique_ptr<TableDriver> make_cia402_table(const Cia402Settings& settings,
                                               const RoleMap& roles) {
  auto s = master_settings(settings, roles);
  if (s) return std::make_unique<Cia402Table>(*s, std::string());
  // inert: nothing is sent, the status is a fault that says why
  cia402::MasterSettings inert;
  inert.node_id = settings.node_id;
  inert.host_node_id = settings.host_node_id;
  inert.counts_per_rev = settings.counts_per_revolution;
  inert.gear_ratio = settings.gear_ratio;
  inert.counts_clockwise = settings.counts_clockwise;
  return std::make_unique<Cia402Table>(inert, "[table.cia402]: " + s.error().message);
}

Status check_cia402_table(const CanConfig& can, const RoleMap& roles) {
  if (!can.table.is_cia402()) return Status{Ok{}};
  auto s = master_settings(can.table.cia402, roles, &can);
  if (!s) return make_error("[table] protocol = \"cia402\": " + s.error().message, s.error().where);
  return Status{Ok{}};
}

}  // namespace turncal::drivers
