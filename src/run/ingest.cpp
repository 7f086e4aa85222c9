#include "turncal/run/ingest.hpp"

#include <algorithm>
#include <cstdio>
#include <numbers>

#include "turncal/drivers/reference.hpp"

namespace turncal::run {

namespace {
constexpr double kBucketS = 1.0;   ///< device seconds per envelope sample
constexpr double kMaxRate = 1e-3;  ///< |rate| held below 0.1%
constexpr double kGateSpanS = 10;  ///< envelope span before the gate applies
}  // namespace

void ClockFit::add(double device_s, double host_s) {
  if (n_ == 0) {
    x0_ = device_s;
    y0_ = host_s;
  }
  const double x = device_s - x0_, y = host_s - y0_;
  ++n_;
  const double n = static_cast<double>(n_);
  const double dx = x - mx_;
  mx_ += dx / n;
  const double dy = y - my_;
  my_ += dy / n;
  cxx_ += dx * (x - mx_);
  cxy_ += dx * (y - my_);
  cyy_ += dy * (y - my_);

  // the lowest sample of each second of device time (a late frame from
  // an earlier second is past: it cannot be lower than what that second had)
  const auto k = static_cast<long>(std::floor(x / kBucketS));
  if (k < current_k_) return;
  line_valid_ = false;
  if (k > current_k_) {
    if (current_k_ >= 0) {
      hull_push(hull_, current_);
      if (seconds_++ == 0) first_x_ = current_.x;
      last_x_ = current_.x;
      sum_x_ += current_.x;
      gate_line_ = edge_over(hull_, sum_x_ / static_cast<double>(seconds_));
    }
    current_k_ = k;
    current_ = {x, y};
  } else if (y - x < current_.y - current_.x) {
    current_ = {x, y};
  }
}

bool ClockFit::add_checked(double device_s, double host_s, double gate_s) {
  if (seconds_ >= 2 && last_x_ - first_x_ >= kGateSpanS) {
    const double r = host_s - y0_ - gate_line_.a - gate_line_.b * (device_s - x0_);
    if (r < -gate_s) return false;
    if (r > gate_s) ++late_;
  }
  add(device_s, host_s);
  return true;
}

double ClockFit::gate_residual(double device_s, double host_s) const {
  if (!(seconds_ >= 2 && last_x_ - first_x_ >= kGateSpanS)) return NAN;
  return host_s - y0_ - gate_line_.a - gate_line_.b * (device_s - x0_);
}

bool TagCheck::LateRun::see(double r, double gate, double host_s) {
  if (!(r > gate) || std::isnan(since_s)) {
    since_s = host_s;
    least_s = INFINITY;
    return true;
  }
  least_s = std::min(least_s, r);
  return false;
}

bool TagCheck::keep(const ClockFit& fit, double device_s, double host_s) {
  const double gate = gate_s();
  const double late_gate = late_gate_s();
  double r = fit.gate_residual(device_s, host_s);
  // Before the fit's gate applies (10 s): against the lowest offset seen,
  // once the tags span a second (a rate within 0.1% moves it 10 ms in 10 s)
  if (std::isnan(r) && have_ && last_device_s_ - first_device_s_ >= kWarmUpS)
    r = (host_s - device_s) - min_offset_s_;
  const bool back = have_ && !(device_s > last_device_s_);
  if (back || r < -gate) {
    ++dropped_;
    if (run_n_++ == 0) {
      run_start_host_s_ = host_s;
      run_back_ = back;
      run_jump_s_ = 0;
    }
    // how far: back from where the next tag was due, or ahead of the clock
    // (the least delayed frame of the run says it best)
    run_jump_s_ = std::max(run_jump_s_, back ? last_device_s_ + last_step_s_ - device_s : -r);
    if (back) back_since_on_time_ = true;
    if (fault_ == Fault::None && host_s - run_start_host_s_ >= kDropRunS) {
      fault_ = run_back_ ? Fault::Back : Fault::Ahead;
      fault_s_ = run_jump_s_;
      fault_n_ = run_n_;
    }
    return false;
  }
  run_n_ = 0;
  if (have_) {
    last_step_s_ = device_s - last_device_s_;
    min_offset_s_ = std::min(min_offset_s_, host_s - device_s);
  } else {
    first_device_s_ = device_s;
    min_offset_s_ = host_s - device_s;
  }
  have_ = true;
  last_device_s_ = device_s;
  if (on_time_.see(r, gate, host_s)) back_since_on_time_ = false;
  on_floor_.see(r, late_gate, host_s);
  // Frames can come late for a while (a bus busy above the device's
  // priority, a transmit backlog) with their tags right: late is a clock
  // that fell behind after 2 s when its tags first went back (beyond the
  // gate: a host's delay never sends a tag back), after 10 s when they did
  // not (it stepped back in a pause of its frames, or runs slow beyond the
  // fit's rate bound; or the bus never lets its frames out in time), then
  // beyond the late gate, which a stand run faster than real time widens
  if (fault_ == Fault::None) {
    if (back_since_on_time_ && r > gate && host_s - on_time_.since_s >= kLateRunS) {
      fault_ = Fault::Late;
      fault_s_ = on_time_.least_s;
      fault_late_for_s_ = kLateRunS;
      fault_gate_s_ = gate;
    } else if (r > late_gate && host_s - on_floor_.since_s >= kLateLongS) {
      fault_ = Fault::Late;
      fault_s_ = on_floor_.least_s;
      fault_late_for_s_ = kLateLongS;
      fault_gate_s_ = late_gate;
    }
  }
  return true;
}

std::string TagCheck::fault(const std::string& what) const {
  char b[160];
  switch (fault_) {
    case Fault::None:
      return {};
    case Fault::Ahead:
    case Fault::Back: {
      const bool ahead = fault_ == Fault::Ahead;
      std::snprintf(b, sizeof b, " %s by %.3f s: %llu frames on end over %.1f s tagged %s",
                    ahead ? "jumped ahead" : "stepped back", fault_s_,
                    static_cast<unsigned long long>(fault_n_), kDropRunS,
                    ahead ? "after they arrived" : "before the last one kept");
      break;
    }
    case Fault::Late:
      std::snprintf(b, sizeof b,
                    " fell behind by %.3f s: every frame for %.0f s came over %.0f ms (of real "
                    "time) later than its tag says",
                    fault_s_, fault_late_for_s_, fault_gate_s_ / scale_ * 1e3);
      break;
  }
  return what + b;
}

void ClockFit::hull_push(std::vector<Point>& hull, const Point& p) {
  while (hull.size() >= 2) {
    const Point& o = hull[hull.size() - 2];
    const Point& q = hull.back();
    // q on or above the segment from o to p: not on the lower hull
    if ((q.x - o.x) * (p.y - o.y) - (q.y - o.y) * (p.x - o.x) > 0) break;
    hull.pop_back();
  }
  hull.push_back(p);
}

ClockFit::Line ClockFit::edge_over(const std::vector<Point>& hull, double mean_x) {
  // The line under every point with the least total distance to them
  // touches the lower hull along the edge over their mean x.
  Line l;
  if (hull.empty()) return l;
  std::size_t i = 0;
  while (i + 2 < hull.size() && hull[i + 1].x < mean_x) ++i;
  if (hull.size() >= 2 && hull[i + 1].x > hull[i].x)
    l.b = (hull[i + 1].y - hull[i].y) / (hull[i + 1].x - hull[i].x);
  l.b = std::clamp(l.b, 1 - kMaxRate, 1 + kMaxRate);
  // the support line of that slope: under every point, touching one
  l.a = hull.front().y - l.b * hull.front().x;
  for (const Point& p : hull) l.a = std::min(l.a, p.y - l.b * p.x);
  return l;
}

const ClockFit::Line& ClockFit::line() const {
  if (!line_valid_) {
    if (current_k_ < 0) {
      line_ = Line{};
    } else {
      std::vector<Point> h = hull_;
      hull_push(h, current_);
      line_ = edge_over(h, (sum_x_ + current_.x) / static_cast<double>(seconds_ + 1));
    }
    line_valid_ = true;
  }
  return line_;
}

double ClockFit::to_host(double device_s) const {
  const Line& l = line();
  return y0_ + l.a + l.b * (device_s - x0_);
}

double ClockFit::to_device(double host_s) const {
  const Line& l = line();
  return x0_ + (host_s - y0_ - l.a) / l.b;
}

double ClockFit::rate_ppm() const {
  return (1 / line().b - 1) * 1e6;
}

double ClockFit::rms_s() const {
  if (n_ < 3) return 0;
  const Line& l = line();
  const double spread = cyy_ - 2 * l.b * cxy_ + l.b * l.b * cxx_;
  const double mean = my_ - l.a - l.b * mx_;
  return std::sqrt(std::max(0.0, spread) / static_cast<double>(n_) + mean * mean);
}

bool StreamHealth::stale(double now_s, double floor_s, double excused_s) const {
  if (std::isnan(last_host_s)) return true;
  const double period = nominal_hz > 0 ? 1 / nominal_hz : 1.0;
  return now_s - last_host_s - std::max(0.0, excused_s) > std::max(10 * period, floor_s);
}

double StreamHealth::rate_hz() const {
  const double span = last_host_s - first_host_s;
  return frames < 2 || !(span > 0) ? 0.0 : static_cast<double>(frames - 1) / span;
}

/// A step from one encoder sample to another the table can make: at most
/// its rate over the host time between them and the slack, plus two counts
/// of the angle signal's resolution.
bool Ingest::plausible_step(double from_host, double from_angle, double host, double angle) const {
  const double dt = std::max(0.0, host - from_host) + plausible_.step_slack_s;
  const double resolution = 2 * table_->angle_resolution_rad();
  return std::abs(angle - from_angle) <= plausible_.max_table_rate_rps * dt + resolution;
}

Ingest::Ingest(const can::Database& db, const RoleMap& roles, Plausibility plausibility)
    : Ingest(db, drivers::make_reference_ins(roles, plausibility),
             drivers::make_reference_table(roles, plausibility), plausibility) {}

Ingest::Ingest(const can::Database& db, std::unique_ptr<InsDriver> ins,
               std::unique_ptr<TableDriver> table, Plausibility plausibility)
    : plausible_(plausibility),
      ins_(std::move(ins)),
      table_(std::move(table)),
      codec_(db),
      // every signal of the widest message: the drivers read a role's
      // signal by its index in its message (an FD message may have more
      // than 64)
      values_(std::max<std::size_t>(codec_.max_signals(), 1)) {
  health_[kVelocity].name = "ins-velocity";
  health_[kInsStatus].name = "ins-status";
  health_[kEncoder].name = "table-encoder";
  health_[kTableStatus].name = "table-status";
}

void Ingest::saw(Stream s, double host_s, double device_s, std::int64_t lost_before) {
  StreamHealth& h = health_[s];
  ++h.frames;
  h.implausible_run = 0;
  if (std::isnan(h.first_host_s)) h.first_host_s = host_s;
  const double prev_host_s = h.last_host_s;
  h.last_host_s = host_s;
  double& last = last_device_s_[s];
  // the device's own count when it keeps one: a SYNC sent late and the
  // next on time are no loss, though their gap is 1.5 periods; the rate is
  // then the mean one while the stream runs (not across a restart), the
  // losses counted in, as the intervals are the SYNCs' jitter
  if (lost_before >= 0 || lost_before == kStreamRestarted) {
    if (lost_before > 0) h.dropped += static_cast<std::uint64_t>(lost_before);
    const bool skip = std::exchange(h.skip_interval, false);
    if (lost_before != kStreamRestarted && !skip && !std::isnan(prev_host_s) &&
        host_s > prev_host_s) {
      h.counted_span_s += host_s - prev_host_s;
      h.counted_periods += 1 + static_cast<std::uint64_t>(lost_before);
      h.nominal_hz = static_cast<double>(h.counted_periods) / h.counted_span_s;
    }
    last = device_s;
    return;
  }
  if (std::isnan(device_s) || device_s == host_s) {
    // no device clock (table status), or one that is the receive time
    // itself (a CiA 402 TPDO without SYNC): the mean receive rate, and no
    // gaps counted, as two frames read in one burst are no period
    h.nominal_hz = h.rate_hz();
    return;
  }
  if (!std::isnan(last)) {
    const double dt = device_s - last;
    if (dt > 0) {
      // the nominal period: the shortest interval the device has shown
      const double hz = 1 / dt;
      if (hz > h.nominal_hz * 1.02 || h.frames < 3) h.nominal_hz = std::max(h.nominal_hz, hz);
      const double periods = dt * h.nominal_hz;
      if (periods > 1.5 && periods < 1e5)
        h.dropped += static_cast<std::uint64_t>(std::llround(periods)) - 1;
    }
  }
  last = device_s;
}

Sample Ingest::implausible(Stream s) {
  ++health_[s].frames;
  ++health_[s].implausible;
  ++health_[s].implausible_run;
  ++implausible_total_;
  return {};
}

void Ingest::clock_sample(ClockFit& fit, double device_s, double host_s) {
  // a time tag far off the line so far is a clock jump or a stuck frame:
  // counted, kept out of the fit
  if (!fit.add_checked(device_s, host_s)) ++counters_.clock_outliers;
}

Sample Ingest::on_frame(const can::Frame& frame, std::int64_t time_ns) {
  ++counters_.frames;
  const double host = host_seconds(time_ns);
  const can::Message* m = nullptr;
  const can::DecodeStatus st = codec_.decode(frame, values_, &m);
  const FrameView view{frame, host, m, st, values_};
  // the INS's frames, then the table's: each driver says whether a frame
  // is its device's
  Decoded d = ins_->decode(view);
  if (d.verdict == Decoded::Verdict::NotMine) d = table_->decode(view);
  switch (d.verdict) {
    case Decoded::Verdict::NotMine:
      break;
    case Decoded::Verdict::Malformed:
      ++counters_.malformed;
      return {};
    case Decoded::Verdict::Implausible:
      return implausible(d.stream);
    case Decoded::Verdict::Pending:
      return {};
    case Decoded::Verdict::Taken:
      return take(std::move(d), host);
  }
  if (st == can::DecodeStatus::UnknownId)
    ++counters_.unknown_id;
  else if (st != can::DecodeStatus::Ok)
    ++counters_.malformed;
  else
    ++counters_.ignored;
  return {};
}

Sample Ingest::poll(double host_s) {
  Decoded d = table_->pending();
  if (d.verdict != Decoded::Verdict::Taken) return {};
  return take(std::move(d), host_s);
}

Sample Ingest::take(Decoded d, double host) {
  switch (d.stream) {
    case kVelocity:
    case kInsStatus:
      saw(d.stream, host, d.device_s);
      if (!std::isnan(d.device_s)) clock_sample(ins_clock_, d.device_s, host);
      break;
    case kEncoder: {
      const double a = std::get<EncoderSample>(d.sample).angle_rad;
      // the step from the last encoder sample, at most the table's rate
      // (twice the stand's limit): a garbled angle must not become a turn
      if (!std::isnan(last_encoder_host_) &&
          !plausible_step(last_encoder_host_, last_encoder_angle_, host, a)) {
        // refused; but refused samples that agree with each other, several in
        // a row, say the reference was the garbled one
        refused_run_ = refused_run_ > 0 && plausible_step(refused_host_, refused_angle_, host, a)
                           ? refused_run_ + 1
                           : 1;
        refused_host_ = host;
        refused_angle_ = a;
        // only a reference with almost nothing after it (the stream's first
        // samples) can be the garbled one; later, a run of agreeing samples
        // off it is a fault of the encoder, refused until the run fails
        if (refused_run_ < kReanchor || accepted_encoder_ > kReanchor) {
          // the losses the device counted before it are losses all the
          // same; the interval across it is no period: out of the mean rate
          if (d.lost_before > 0)
            health_[kEncoder].dropped += static_cast<std::uint64_t>(d.lost_before);
          health_[kEncoder].skip_interval = true;
          return implausible(kEncoder);
        }
        ++counters_.encoder_reanchored;
        accepted_encoder_ = 0;
      }
      refused_run_ = 0;
      ++accepted_encoder_;
      table_->accept_encoder();
      last_encoder_host_ = host;
      last_encoder_angle_ = a;
      saw(kEncoder, host, d.device_s, d.lost_before);
      clock_sample(table_clock_, d.device_s, host);
      break;
    }
    case kTableStatus:
      saw(kTableStatus, host, d.device_s);
      break;
    case kStreams:
      break;
  }
  return std::move(d.sample);
}

}  // namespace turncal::run
