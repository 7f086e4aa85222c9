#include "turncal/run/record.hpp"

#include "turncal/estimation/nominal.hpp"

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace turncal::run {
namespace {

/// Asks the kernel to back the whole pages of [p, p + bytes) with huge
/// pages where it can: a vector of a run's samples (17 MB for two hours)
/// then takes a few page faults as it fills instead of thousands. A hint:
/// where the kernel declines (no transparent huge pages), the values are
/// the same, so its result is not an error.
void advise_huge_pages(const void* p, std::size_t bytes) noexcept {
  const long page = sysconf(_SC_PAGESIZE);
  if (page <= 0 || bytes == 0) return;
  const auto size = static_cast<std::uintptr_t>(page);
  const auto a = reinterpret_cast<std::uintptr_t>(p);
  const std::uintptr_t from = (a + size - 1) / size * size, to = (a + bytes) / size * size;
  if (to > from)
    (void)madvise(reinterpret_cast<void*>(from), to - from, MADV_HUGEPAGE);  // a hint only
}

}  // namespace

void Record::add(const Sample& s) {
  if (const auto* v = std::get_if<VelocitySample>(&s)) {
    if (!velocity_tags_.keep(ins_clock_, v->t_ins_s, v->host_s)) return;
    constexpr std::size_t kRateSamples = 256;
    if (velocity_.size() == kRateSamples && expected_span_s_ > 0) {
      const double seen = velocity_.back().t_s - velocity_.front().t_s;
      if (seen > 0) {
        const double rate = static_cast<double>(kRateSamples - 1) / seen;
        // 2% above the rate seen: a clock a little fast still fits
        const double n = rate * 1.02 * expected_span_s_;
        if (n < 1e9) {
          velocity_.reserve(std::max(kRateSamples, static_cast<std::size_t>(n)));
          if (huge_pages_)
            advise_huge_pages(velocity_.data(), velocity_.capacity() * sizeof(est::VelocityObs));
        }
      }
    }
    velocity_.push_back({v->t_ins_s, v->ve, v->vn});
    if (!ins_clock_.add_checked(v->t_ins_s, v->host_s, velocity_tags_.gate_s())) ++clock_outliers_;
    return;
  }
  const auto* e = std::get_if<EncoderSample>(&s);
  if (e == nullptr) return;
  if (!encoder_tags_.keep(table_clock_, e->t_table_s, e->host_s)) return;
  if (!table_clock_.add_checked(e->t_table_s, e->host_s, encoder_tags_.gate_s())) ++clock_outliers_;
  if (pending_ && e->angle_rad == last_.angle_rad) {
    last_ = *e;  // the constant run goes on: only its ends are kept
    return;
  }
  close();
  encoder_.push_back(*e);
  last_ = *e;
  pending_ = true;
}

std::string Record::clock_fault() const {
  std::string f = velocity_tags_.fault("the INS clock");
  return f.empty() ? encoder_tags_.fault("the table clock") : f;
}

void Record::close() {
  // the end of the constant run, unless it is already kept
  if (pending_ && encoder_.back().t_table_s != last_.t_table_s) encoder_.push_back(last_);
}

est::EstimationInput input_of_plan(const Plan& plan, double sample_rate_hz) {
  est::EstimationInput in;
  in.timeline.site = plan.site;
  in.timeline.noise = plan.noise();
  in.timeline.epoch_s = plan.epoch_s;
  in.priors = plan.priors;
  in.priors.align_s = plan.profile.align_s;
  in.sigma_z = plan.sigma_z;
  in.mean_measurement = plan.mean_measurement;
  in.sample_rate_hz = sample_rate_hz;
  in.sharp_ratio = plan.sharp_ratio;
  return in;
}

// Two-sample slopes over 10 ms read 1.77 rad/s on a 0.52 rad/s turn of a
// virtual CiA 402 drive timed by receipt, in a loaded guest.
double peak_rate_rps(const std::vector<est::AngleSample>& enc, std::size_t from, std::size_t to) {
  // |slope| of psi on t over samples j..k, about the first (no cancellation)
  auto slope = [&](std::size_t j, std::size_t k) {
    double st = 0, sp = 0, stt = 0, stp = 0;
    const double n = static_cast<double>(k - j + 1);
    for (std::size_t i = j; i <= k; ++i) {
      const double t = enc[i].t_s - enc[j].t_s;
      const double p = enc[i].psi_rad - enc[j].psi_rad;
      st += t;
      sp += p;
      stt += t * t;
      stp += t * p;
    }
    const double den = n * stt - st * st;
    return den > 0 ? std::abs((n * stp - st * sp) / den) : 0.0;
  };
  // a motion shorter than the window: its samples' one fit
  if (enc[to].t_s - enc[from].t_s < kPeakWindowS) return slope(from, to);
  double peak = 0;
  for (std::size_t j = from, k = from; j <= to; ++j) {
    while (k < to && enc[k].t_s - enc[j].t_s < kPeakWindowS) ++k;
    if (enc[k].t_s - enc[j].t_s < kPeakWindowS) break;  // no whole window left
    peak = std::max(peak, slope(j, k));
  }
  return peak;
}

Result<BuiltInput> build_input(Record& record, const Plan& plan, const BuildSettings& settings) {
  const ClockFit& ins = record.ins_clock();
  const ClockFit& table = record.table_clock();
  BuiltInput out;
  const auto& vel = record.velocity();
  if (vel.empty()) return Error{"no INS velocity in the record: the INS never navigated"};
  const auto& enc_raw = record.encoder();
  if (enc_raw.empty()) return Error{"no table encoder frame in the record"};
  if (ins.count() == 0 || table.count() == 0)
    return Error{"no device clock could be fitted (no time-tagged frame of the INS or table)"};
  const double t0 = vel.front().t_s;
  out.t0_ins_s = t0;
  const double duration = plan.profile.duration_s;

  est::EstimationInput& in = out.input;
  in = input_of_plan(plan, settings.sample_rate_hz);
  // the nonlinear second pass where the first pass says linearisation
  // matters (model.md, 8)
  in.second_pass.nominal = &est::strapdown_nominal;
  in.second_pass.mode = settings.second_pass;
  // the velocity from t0, in place: the record's samples become the input's
  in.velocity = record.take_velocity();
  std::size_t used = 0;
  for (est::VelocityObs& v : in.velocity) {
    v.t_s -= t0;
    if (v.t_s > duration + 1e-6) break;
    ++used;
  }
  in.velocity.resize(used);
  out.velocity_used = in.velocity.size();
  for (const auto& [tags, what] : {std::pair{&record.velocity_tags(), "INS velocity samples"},
                                   std::pair{&record.encoder_tags(), "encoder samples"}})
    if (tags->dropped() > 0)
      out.notes.push_back(std::to_string(tags->dropped()) + " " + what +
                          " left out: their time tags did not move forward or put them after "
                          "their receipt, off the device's clock");
  const double recorded = in.velocity.back().t_s;
  if (recorded < duration - 1.0)
    out.notes.push_back("the record ends " + std::to_string(duration - recorded) +
                        " s before the planned end: estimated over what there is");

  // encoder onto the INS clock, model sense
  std::vector<est::AngleSample>& enc = in.timeline.encoder;
  enc.reserve(enc_raw.size());
  for (const EncoderSample& e : enc_raw) {
    const double t = ins.to_device(table.to_host(e.t_table_s)) - t0;
    if (!enc.empty() && t <= enc.back().t_s) continue;
    enc.push_back({t, e.angle_rad - settings.heading_offset_rad});
  }

  // motions: steps above the jitter, merged when close in time
  struct Span {
    std::size_t from, to;  // sample indices: last still before, first still after
  };
  std::vector<Span> spans;
  for (std::size_t k = 1; k < enc.size(); ++k) {
    if (std::abs(enc[k].psi_rad - enc[k - 1].psi_rad) <= settings.jitter_rad) continue;
    if (!spans.empty() && enc[k - 1].t_s - enc[spans.back().to].t_s <= settings.merge_s)
      spans.back().to = k;
    else
      spans.push_back({k - 1, k});
  }
  // each motion padded by still samples on both sides (up to merge_s / 2):
  // the last steps into rest can be smaller than the jitter
  for (std::size_t i = 0; i < spans.size(); ++i) {
    Span& s = spans[i];
    const std::size_t lo = i == 0 ? 0 : spans[i - 1].to;
    const std::size_t hi = i + 1 == spans.size() ? enc.size() - 1 : spans[i + 1].from;
    const double ta = enc[s.from].t_s - settings.merge_s / 2;
    const double tb = enc[s.to].t_s + settings.merge_s / 2;
    while (s.from > lo && enc[s.from - 1].t_s >= ta) --s.from;
    while (s.to < hi && enc[s.to + 1].t_s <= tb) ++s.to;
  }
  std::vector<Span> in_run;
  for (const Span& s : spans) {
    const double ta = enc[s.from].t_s, tb = enc[s.to].t_s;
    if (tb <= 0) continue;  // before t0: the move to the start angle
    if (ta < 0)
      return Error{"the table moved at t0 (from " + std::to_string(ta) + " s to " +
                   std::to_string(tb) + " s): the holds are not still"};
    if (ta >= duration) continue;
    in_run.push_back(s);
  }
  const bool matches_plan = in_run.size() == plan.profile.turns.size();
  if (!matches_plan)
    out.notes.push_back("the encoder shows " + std::to_string(in_run.size()) +
                        " turns, the profile plans " + std::to_string(plan.profile.turns.size()) +
                        ": turns taken from the encoder alone");
  for (std::size_t i = 0; i < in_run.size(); ++i) {
    const Span& s = in_run[i];
    TurnAchieved a{enc[s.from].t_s, enc[s.to].t_s, enc[s.to].psi_rad - enc[s.from].psi_rad, 0};
    a.peak_rate_rps = peak_rate_rps(enc, s.from, s.to);
    est::TurnWindow w{a.t_start_s, a.t_end_s};
    if (matches_plan) {
      const TurnSpec& p = plan.profile.turns[i];
      a.planned_angle_rad = p.angle_rad;
      w.angle_rad = p.angle_rad;
      TableMotion m;
      w.plateau_rate_rps = m.move_by(0, p.angle_rad, p.max_rate_rps, p.max_accel_rps2).peak_rate;
    }
    in.timeline.turns.push_back(w);
    out.turns.push_back(a);
  }

  in.timeline.duration_s = std::min(duration, recorded);
  in.timeline.psi_start_rad = est::psi_at(enc, 0.0);
  in.with_two_stage = settings.two_stage;
  return out;
}

}  // namespace turncal::run
