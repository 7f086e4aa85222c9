// Received frames into typed samples (style.md, 1-3): decoded by the DBC
// and the roles, device time tags unwrapped into seconds, the table's
// wrapping angle into a multi-turn angle, and the device clocks fitted
// against the host's receive time so that everything lands on the INS
// clock, the experiment's timeline (can-icd.md). Per-role health: rate,
// drops, age, stale. Pure: no sockets, no clocks; the daemon, the replay
// and the tests feed it the same way.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "turncal/can/dbc.hpp"
#include "turncal/can/frame.hpp"
#include "turncal/config.hpp"
#include "turncal/device.hpp"
#include "turncal/unwrap.hpp"

namespace turncal::run {

/// The line host = a + b device of one device clock against the host's
/// receive times. A frame reaches the host some latency after the device
/// stamped it, never before; the latency is a floor plus delays (a loaded
/// host, a burst after a stall) that can last long and come in runs. So the
/// fit is the lower envelope of the samples, not their mean: the line under
/// every sample that lies closest to them on average (a linear programme,
/// Moon, Skelly and Towsley, "Estimation and removal of clock skew from
/// network delay measurements", 1999), solved on the lowest sample of each
/// second of device time. Delays, however long or frequent, leave it where
/// the undelayed frames put it; the latency floor is common to the
/// device clocks of one bus and cancels when one is mapped onto another.
/// The rate is held within 0.1% of the host's (crystals are within
/// 0.01%), so a few seconds of samples cannot tilt it far.
class ClockFit {
 public:
  void add(double device_s, double host_s);
  /// Adds the pair unless, once the envelope spans 10 s, it lies more than
  /// `gate_s` below it (a device clock that jumped, or a garbled tag):
  /// then returns false. Late pairs are added (they cannot lower the
  /// envelope) and counted late when more than `gate_s` above it.
  bool add_checked(double device_s, double host_s, double gate_s = 0.05);
  [[nodiscard]] std::size_t count() const { return n_; }
  /// host - the envelope's host time of `device_s`, s, once the envelope
  /// spans 10 s (the line add_checked gates on); NaN before.
  [[nodiscard]] double gate_residual(double device_s, double host_s) const;
  /// Pairs that came more than the gate late.
  [[nodiscard]] std::size_t late() const { return late_; }
  /// Host time of a device time; with one sample, rate 1.
  [[nodiscard]] double to_host(double device_s) const;
  [[nodiscard]] double to_device(double host_s) const;
  /// Device rate against the host, ppm (device fast: negative slope - 1).
  [[nodiscard]] double rate_ppm() const;
  /// host - fitted host, s: the pair's delay over the envelope.
  [[nodiscard]] double residual(double device_s, double host_s) const {
    return host_s - to_host(device_s);
  }
  /// RMS of the delays over the envelope, s.
  [[nodiscard]] double rms_s() const;

 private:
  struct Point {
    double x, y;  ///< device, host about the first sample
  };
  struct Line {
    double a = 0, b = 1;  ///< y = a + b x
  };
  /// Appends a point (ascending x) to a lower convex hull.
  static void hull_push(std::vector<Point>& hull, const Point& p);
  /// The hull's edge over the mean x, as a line held within the rate bound.
  static Line edge_over(const std::vector<Point>& hull, double mean_x);
  [[nodiscard]] const Line& line() const;
  std::size_t n_ = 0, late_ = 0;
  double x0_ = 0, y0_ = 0;              // first sample: the origin
  double mx_ = 0, my_ = 0;              // means of all samples about the origin
  double cxx_ = 0, cxy_ = 0, cyy_ = 0;  // their co-moments
  std::vector<Point> hull_;             // lower hull of the finished seconds' lowest samples
  std::size_t seconds_ = 0;             // finished seconds
  double first_x_ = 0, last_x_ = 0, sum_x_ = 0;  // of their lowest samples
  Point current_{0, 0};                          // lowest of the second under way
  long current_k_ = -1;
  Line gate_line_;  ///< the envelope of the finished seconds
  mutable Line line_;
  mutable bool line_valid_ = false;
};

/// A device's time tags checked against its clock, sample by sample, before
/// a sample is kept: a tag that does not move forward (a clock that stepped
/// back, a stuck or repeated tag), or one that puts the sample's sending
/// after its receipt by more than the gate (a clock that jumped ahead, a
/// garbled tag) is dropped and counted. A jump that lasts is a fault: tags
/// dropped for 0.5 s on end (the clock jumped ahead, or back by more than
/// that), or every sample more than the gate late for 2 s after tags that
/// went back (it jumped back by less), or for 10 s with none that did. Until the clock's fit spans
/// 10 s, the clock is the lowest offset host - device seen (after the first second of tags, in
/// which a jump ahead is not seen). Samples of a clock that jumped would land at the wrong time in
/// the estimate; a run cannot go on from there. Pure, like the record.
class TagCheck {
 public:
  static constexpr double kGateS = 0.05;
  static constexpr double kDropRunS = 0.5;
  static constexpr double kLateRunS = 2.0;    ///< late, after tags that went back
  static constexpr double kLateLongS = 10.0;  ///< late, with none that did
  static constexpr double kWarmUpS = 1.0;     ///< tags a jump ahead is not seen in
  /// Host times are stand seconds, and a real second is `scale` of them
  /// (the stand's time_scale): the gate is real time, a frame's delay, so
  /// it scales; the runs' lengths (0.5 s, 2 s, 10 s) are stand time.
  /// `late_floor_s` (stand seconds, SequencerSettings::real_time_floor_s)
  /// is how far behind real time a stand run faster than real time may
  /// fall on a busy host before its frames count as late: its tags are
  /// the simulation's own time, right however late the host sends them,
  /// and a clock that runs slow is a real device's fault, not a host's.
  /// It widens the late side of the gate only, for frames late with no tag
  /// that went back: a delay never puts a tag ahead of its receipt, nor one
  /// before the last.
  [[nodiscard]] double gate_s() const { return kGateS * scale_; }
  [[nodiscard]] double late_gate_s() const { return gate_s() + late_floor_s_; }
  void set_time_scale(double scale, double late_floor_s = 0) {
    scale_ = scale > 0 ? scale : 1.0;
    late_floor_s_ = late_floor_s > 0 ? late_floor_s : 0.0;
  }
  /// `fit` is the clock as fitted before this sample. The first fault is
  /// kept; checking goes on after it.
  bool keep(const ClockFit& fit, double device_s, double host_s);
  [[nodiscard]] std::uint64_t dropped() const { return dropped_; }
  /// Why the clock cannot be trusted any more ("" while it can); `what`
  /// names the device's clock ("INS clock").
  [[nodiscard]] std::string fault(const std::string& what) const;
  /// fault() is not "": a test for every sample, with no string built.
  [[nodiscard]] bool faulted() const { return fault_ != Fault::None; }

 private:
  bool have_ = false;
  double last_device_s_ = 0;
  double first_device_s_ = 0;
  double min_offset_s_ = 0;          ///< least host - device of the kept samples
  double last_step_s_ = 0;           ///< between the last two kept tags
  double run_start_host_s_ = NAN;    ///< first of the drops on end
  double run_jump_s_ = 0;            ///< how far its tags were off, at most
  bool run_back_ = false;            ///< the run began with a tag that went back
  bool back_since_on_time_ = false;  ///< a tag went back since the last on-time frame
  double fault_late_for_s_ = 0;
  double fault_gate_s_ = 0;  ///< the gate a late fault's frames were beyond
  double scale_ = 1;
  double late_floor_s_ = 0;
  std::uint64_t run_n_ = 0;
  /// Frames late beyond a gate: since when none was within it
  struct LateRun {
    double since_s = NAN;       ///< the last sample within the gate (host time)
    double least_s = INFINITY;  ///< the least delay of the late run so far
    /// Sees a kept sample's delay `r`; true when it is within `gate` (or
    /// the first), which starts the run again.
    bool see(double r, double gate, double host_s);
  };
  LateRun on_time_;   ///< beyond the gate
  LateRun on_floor_;  ///< beyond the late gate (the gate and the floor)
  std::uint64_t dropped_ = 0;
  enum class Fault : std::uint8_t { None, Ahead, Back, Late } fault_ = Fault::None;
  double fault_s_ = 0;  ///< how far the clock was off, s
  std::uint64_t fault_n_ = 0;
};

using turncal::AngleUnwrap;
using turncal::EncoderSample;
using turncal::HostCommandSample;
using turncal::InsStatusSample;
using turncal::kEncoder;
using turncal::kInsStatus;
using turncal::kStreams;
using turncal::kTableStatus;
using turncal::kVelocity;
using turncal::Plausibility;
using turncal::Sample;
using turncal::Stream;
using turncal::TableStatusSample;
using turncal::TagUnwrap;
using turncal::VelocitySample;

/// What the host hears of one kind of frame.
struct StreamHealth {
  std::string name;
  /// Learned from the time tags (the shortest interval), or the mean rate
  /// (receive times; for a device that counts its own losses, the periods
  /// over the time it ran, losses in)
  double nominal_hz = 0;
  std::uint64_t frames = 0;   ///< received
  std::uint64_t dropped = 0;  ///< gaps in the device's time tags, or its own count of losses
  /// A stream that counts its own losses: the receive time and the
  /// device's periods (samples and losses) between its samples, restarts
  /// left out; their ratio is its nominal rate
  double counted_span_s = 0;
  std::uint64_t counted_periods = 0;
  bool skip_interval = false;  ///< a sample refused since the last: the next interval left out
  /// Frames whose values cannot be (outside their DBC range, a velocity
  /// beyond the bound, an encoder step beyond the table's rate): counted in
  /// `frames`, skipped, and not seen (a stream of nothing else goes stale).
  std::uint64_t implausible = 0;
  std::uint64_t implausible_run = 0;  ///< implausible frames since the last good one
  double first_host_s = NAN;
  double last_host_s = NAN;
  /// Not seen for 10 nominal periods, and for at least `floor_s` (or never
  /// seen), its silence less `excused_s` (of it, the time the host was not
  /// running its loop, so not listening).
  [[nodiscard]] bool stale(double now_s, double floor_s = 0, double excused_s = 0) const;
  [[nodiscard]] double age_s(double now_s) const { return now_s - last_host_s; }
  /// Mean rate since the first frame, Hz.
  [[nodiscard]] double rate_hz() const;
};

struct IngestCounters {
  std::uint64_t frames = 0;
  std::uint64_t unknown_id = 0;        ///< no message in the DBC
  std::uint64_t malformed = 0;         ///< wrong length, or a role signal not a number
  std::uint64_t ignored = 0;           ///< known, but no role of turncal's
  std::uint64_t clock_outliers = 0;    ///< time tags off their clock fit by over 50 ms
  std::uint64_t half_pairs = 0;        ///< a velocity frame whose other half never came
  std::uint64_t velocity_untimed = 0;  ///< velocity left out: no time frame just before it
  /// Encoder references given up: several samples in a row agreed with
  /// each other and not with it (a garbled sample had become it).
  std::uint64_t encoder_reanchored = 0;
};

class Ingest {
 public:
  /// The reference stand's devices (can-icd.md) through `roles`; `db` and
  /// `roles` must outlive it.
  Ingest(const can::Database& db, const RoleMap& roles, Plausibility plausibility = {});
  /// The stand's own devices; `db` must outlive it.
  Ingest(const can::Database& db, std::unique_ptr<InsDriver> ins,
         std::unique_ptr<TableDriver> table, Plausibility plausibility = {});
  /// One received frame; host time from its receive timestamp, truncated
  /// to microseconds as a candump log keeps it, so that a replay of the
  /// log sees exactly what the live run saw.
  Sample on_frame(const can::TimedFrame& f) { return on_frame(f.frame, f.time_ns); }
  /// The same, the frame and its receive time apart (no copy of the frame).
  Sample on_frame(const can::Frame& frame, std::int64_t time_ns);
  /// A sample the table driver holds beyond the frames' (a status change
  /// that came with an encoder sample, or from a timeout), at host_s;
  /// monostate when none. Call until monostate after each frame and tick.
  Sample poll(double host_s);
  [[nodiscard]] const StreamHealth& health(Stream s) const { return health_[s]; }
  /// The counts so far (the INS driver's own, of half pairs and untimed
  /// velocity, read as asked: two virtual calls a frame for a count read
  /// by a status or a report).
  [[nodiscard]] IngestCounters counters() const {
    IngestCounters c = counters_;
    c.half_pairs = ins_->half_pairs();
    c.velocity_untimed = ins_->untimed();
    return c;
  }
  /// Implausible frames of every stream so far.
  [[nodiscard]] std::uint64_t implausible_total() const { return implausible_total_; }
  [[nodiscard]] InsDriver& ins() { return *ins_; }
  [[nodiscard]] TableDriver& table() { return *table_; }
  [[nodiscard]] const InsDriver& ins() const { return *ins_; }
  [[nodiscard]] const TableDriver& table() const { return *table_; }
  [[nodiscard]] const ClockFit& ins_clock() const { return ins_clock_; }
  [[nodiscard]] const ClockFit& table_clock() const { return table_clock_; }
  /// INS clock time of a table clock time, through the host's timeline.
  [[nodiscard]] double table_to_ins(double t_table_s) const {
    return ins_clock_.to_device(table_clock_.to_host(t_table_s));
  }
  /// Host time of microseconds resolution, s.
  static double host_seconds(std::int64_t time_ns) {
    return static_cast<double>(time_ns / 1000) * 1e-6;
  }

 private:
  /// lost_before: the device's own count of samples lost before this one
  /// (Decoded::lost_before); -1: counted from the gap in device time.
  void saw(Stream s, double host_s, double device_s, std::int64_t lost_before = -1);
  /// A frame of `s` that cannot be: counted, and nothing more.
  Sample implausible(Stream s);
  Plausibility plausible_;
  std::uint64_t implausible_total_ = 0;
  double last_encoder_host_ = NAN, last_encoder_angle_ = NAN;
  /// Encoder samples refused in a row that agree with each other: when
  /// kReanchor of them do and the reference had at most kReanchor samples
  /// after it (the stream's first ones), the reference was the bad one (a
  /// garbled first sample), and the latest becomes it.
  int refused_run_ = 0;
  std::uint64_t accepted_encoder_ = 0;  ///< since the stream's first sample or its re-anchoring
  double refused_host_ = NAN, refused_angle_ = NAN;
  static constexpr int kReanchor = 3;
  [[nodiscard]] bool plausible_step(double from_host, double from_angle, double host,
                                    double angle) const;
  void clock_sample(ClockFit& fit, double device_s, double host_s);
  /// A driver's sample: its stream's health, its clock, the encoder's step.
  Sample take(Decoded d, double host_s);
  std::unique_ptr<InsDriver> ins_;
  std::unique_ptr<TableDriver> table_;
  can::FrameCodec codec_;
  std::vector<double> values_;
  ClockFit ins_clock_, table_clock_;
  std::array<StreamHealth, kStreams> health_;
  std::array<double, kStreams> last_device_s_{NAN, NAN, NAN, NAN};
  IngestCounters counters_;
};

}  // namespace turncal::run
