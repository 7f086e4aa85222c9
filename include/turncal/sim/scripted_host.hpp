// A host that runs a plan's experiment on a virtual stand the way turncald
// will, by the clock and without looking back: heartbeat at 10 Hz, enable
// the table, align the INS with the heading from the table, turn as the
// profile says (relative to t0), until the run's end. turncal-sim's offline
// mode uses it to write a whole run; tests use it to drive the stand.
#pragma once

#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "turncal/can/candump.hpp"
#include "turncal/can/dbc.hpp"
#include "turncal/config.hpp"
#include "turncal/plan.hpp"
#include "turncal/sim/virtual_stand.hpp"

namespace turncal::stand {

/// The injected errors of a virtual INS drawn from the plan's priors (the
/// noise and the simulation's own seed too): the truth of a simulated run.
sim::Config draw_truth(const Plan& plan, std::uint64_t seed);

class ScriptedHost {
 public:
  /// `roles` must outlive the host. heading_offset: the stand's mounting
  /// (can-icd.md): heading of z2 = heading_offset - table angle.
  ScriptedHost(const Plan& plan, const RoleMap& roles, double heading_offset_rad);
  /// Host frames due in (last t, t], given the stand's state at t.
  void step(double t, const VirtualStand& stand, std::vector<StandFrame>& out);
  /// True once the run has gone `duration_s` past t0, or a command did
  /// not fit its signal.
  [[nodiscard]] bool done() const { return done_; }
  /// Why the run ended early: a command that did not fit (nothing clipped
  /// is sent); nullptr otherwise.
  [[nodiscard]] const Error* error() const { return error_ ? &*error_ : nullptr; }
  static constexpr double kEnableAt = 1.0;  ///< stand time of the enable, s
  static constexpr double kAlignAt = 2.0;   ///< stand time of the alignment command, s

 private:
  /// Encodes (checked) and appends a frame, or records the error and ends.
  void send(std::vector<StandFrame>& out, double t, bool ins_side, Role any,
            std::initializer_list<std::pair<Role, double>> values);
  Plan plan_;
  const RoleMap& roles_;
  double heading_offset_;
  long heartbeat_k_ = 0;
  std::uint8_t seq_ = 0;
  std::size_t next_turn_ = 0;
  bool enabled_ = false, aligning_ = false, done_ = false;
  std::optional<Error> error_;
};

/// The virtual stand in 1 ms ticks of simulated time, with an optional
/// scripted host: what turncal-sim runs, offline and live alike, so that
/// both produce the same frames.
class StandLoop {
 public:
  static constexpr double kTick = 1e-3;
  /// `script`: the plan a ScriptedHost runs, or nullptr for an outside host.
  StandLoop(const StandSetup& setup, const can::Database& db, const RoleMap& roles,
            const Plan* script);
  /// Runs the next tick: host frames from the bus (received since the last
  /// tick) are applied at its time; `out` gets every frame of the tick, the
  /// stand's and the scripted host's, in time order.
  void tick(std::span<const can::Frame> from_bus, std::vector<StandFrame>& out);
  /// Simulated time of the next tick.
  [[nodiscard]] double next_time() const { return static_cast<double>(k_) * kTick; }
  /// The scripted host has finished its run (never, without a script).
  [[nodiscard]] bool done() const { return host_ != nullptr && host_->done(); }
  /// Why the scripted host ended its run early, or nullptr.
  [[nodiscard]] const Error* error() const { return host_ != nullptr ? host_->error() : nullptr; }
  [[nodiscard]] const VirtualStand& stand() const { return stand_; }
  [[nodiscard]] VirtualStand& stand() { return stand_; }

 private:
  VirtualStand stand_;
  std::unique_ptr<ScriptedHost> host_;
  std::vector<StandFrame> from_host_;
  long k_ = 0;
};

/// A whole run of `plan` on a virtual stand driven by a ScriptedHost in
/// 1 ms ticks, every frame of both directions written to `log` in time
/// order (interfaces from `can`, times from `start_time_s`, Unix seconds).
Status run_offline(const Plan& plan, const CanConfig& can, const can::Database& db,
                   const RoleMap& roles, const StandSetup& setup, can::LogWriter& log,
                   double start_time_s);

}  // namespace turncal::stand
