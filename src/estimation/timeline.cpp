#include "turncal/estimation/timeline.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

namespace turncal::est {
namespace {

/// How one turn window is propagated.
struct ResolvedTurn {
  TurnWindow w;
  std::vector<AngleSample> samples;  // first at t_start, last at t_end
  TurnSource source = TurnSource::Encoder;
  TurnIntegrals closed_form{0, 0};  // used when source is ClosedForm
};

std::string at_turn(std::size_t i, const TurnWindow& w) {
  return "turn " + std::to_string(i + 1) + " (" + std::to_string(w.t_start_s) + " s to " +
         std::to_string(w.t_end_s) + " s)";
}

/// Decides, turn by turn, between the encoder samples (model.md, 7) and the
/// constant-rate closed form when the encoder has a gap in the window.
Result<std::vector<ResolvedTurn>> resolve_turns(const TimelineInput& in) {
  std::vector<ResolvedTurn> out;
  const std::span<const AngleSample> enc(in.encoder);
  double psi_hold = in.psi_start_rad;
  for (std::size_t i = 0; i < in.turns.size(); ++i) {
    ResolvedTurn r;
    r.w = in.turns[i];
    const double t1 = r.w.t_start_s, t2 = r.w.t_end_s;
    if (!(t2 > t1)) return make_error(at_turn(i, r.w) + ": the turn must end after it starts");
    const double t_next = i + 1 < in.turns.size() ? in.turns[i + 1].t_start_s : in.duration_s;
    auto first = std::upper_bound(enc.begin(), enc.end(), t1,
                                  [](double v, const AngleSample& s) { return v < s.t_s; });
    auto last = std::lower_bound(enc.begin(), enc.end(), t2,
                                 [](const AngleSample& s, double v) { return s.t_s < v; });
    // Coverage: a sample at or before t1, one at or after t2, and no gap
    // between consecutive ones longer than the limit.
    bool covered = first != enc.begin() && last != enc.end();
    if (covered)
      for (auto it = first - 1; it != last && covered; ++it)
        covered = (it + 1)->t_s - it->t_s <= in.max_encoder_gap_s;
    if (covered) {
      r.samples.push_back({t1, psi_at(enc, t1)});
      for (auto it = first; it != last; ++it) r.samples.push_back(*it);
      r.samples.push_back({t2, psi_at(enc, t2)});
    } else {
      // The closed form: the angle from the hold before and the encoder
      // after the turn if it speaks again before the next turn, else the
      // plan; the bounded terms along a uniform angle sweep.
      const bool after = last != enc.end() && last->t_s < t_next;
      if (!after && !std::isfinite(r.w.angle_rad))
        return make_error(at_turn(i, r.w) +
                          ": the encoder has a gap in the turn and no angle after it, and the "
                          "turn has no planned angle to fall back on");
      if (!std::isfinite(r.w.plateau_rate_rps) || !(r.w.plateau_rate_rps > 0))
        return make_error(at_turn(i, r.w) +
                          ": the encoder has a gap in the turn, and the turn has no planned "
                          "plateau rate for the constant-rate closed form");
      const double psi1 = psi_hold;
      const double psi2 = after ? last->psi_rad : psi1 + r.w.angle_rad;
      const int n = std::max(2, static_cast<int>(std::ceil((t2 - t1) / 0.005)));
      for (int k = 0; k <= n; ++k) {
        const double f = static_cast<double>(k) / n;
        r.samples.push_back({t1 + f * (t2 - t1), psi1 + f * (psi2 - psi1)});
      }
      r.source = TurnSource::ClosedForm;
      const double rate = std::copysign(r.w.plateau_rate_rps, psi2 - psi1);
      r.closed_form = turn_integrals_constant_rate(psi1, psi2, rate);
    }
    psi_hold = r.samples.back().psi_rad;
    out.push_back(std::move(r));
  }
  return out;
}

std::vector<HoldSpan> holds_of(const TimelineInput& in, const std::vector<ResolvedTurn>& turns) {
  std::vector<HoldSpan> holds;
  double t = 0, psi = in.psi_start_rad;
  for (const ResolvedTurn& r : turns) {
    holds.push_back({t, r.w.t_start_s, psi});
    t = r.w.t_end_s;
    psi = r.samples.back().psi_rad;
  }
  holds.push_back({t, in.duration_s, psi});
  return holds;
}

}  // namespace

namespace {

/// A measurement time of the schedule.
struct Mark {
  double t;
  bool boundary;
};

constexpr double kSameTime = 1e-9;  // s: two marks closer than this are one

/// The measurement schedule: the epochs not inside a turn and the turns'
/// boundary samples, ascending.
std::vector<Mark> schedule(const TimelineInput& in, const std::vector<ResolvedTurn>& turns) {
  std::vector<Mark> marks;
  const auto n_epochs = static_cast<long>(std::floor(in.duration_s / in.epoch_s + 1e-9));
  std::size_t i = 0;
  for (long k = 1; k <= n_epochs; ++k) {
    const double t = static_cast<double>(k) * in.epoch_s;
    while (i < turns.size() && turns[i].w.t_end_s < t) ++i;
    if (i < turns.size() && turns[i].w.t_start_s <= t) continue;  // within turn i
    marks.push_back({t, false});
  }
  for (const ResolvedTurn& r : turns) {
    if (std::isfinite(r.w.sample_before_s)) marks.push_back({r.w.sample_before_s, true});
    if (std::isfinite(r.w.sample_after_s) && r.w.sample_after_s <= in.duration_s + kSameTime)
      marks.push_back({r.w.sample_after_s, true});
  }
  std::sort(marks.begin(), marks.end(), [](const Mark& a, const Mark& b) { return a.t < b.t; });
  std::vector<Mark> out;
  for (const Mark& m : marks) {
    if (!out.empty() && m.t - out.back().t < kSameTime) {
      out.back().boundary = out.back().boundary || m.boundary;  // the exact sample
      continue;
    }
    out.push_back(m);
  }
  return out;
}

/// The composition of `piece` after `d` (d := piece o d).
void compose(Discrete& d, const Discrete& piece) {
  d.q = piece.phi * d.q * piece.phi.transpose() + piece.q;
  d.phi = piece.phi * d.phi;
}

}  // namespace

Result<TimelineReport> for_each_step(const TimelineInput& in,
                                     const std::function<void(const TimelineStep&)>& fn) {
  if (!(in.epoch_s > 0)) return make_error("the filter epoch must be positive");
  if (in.nominal &&
      (!in.nominal->track || in.nominal->track->empty() || !(in.nominal->track->front().t_s <= 0)))
    return make_error("the nominal has no navigation state from t0 to linearise about");
  TURNCAL_ASSIGN(turns, resolve_turns(in));
  for (std::size_t i = 0; i < turns.size(); ++i) {
    const TurnWindow& w = turns[i].w;
    const double before_end = i == 0 ? 0.0 : turns[i - 1].w.t_end_s;
    const double after_start =
        i + 1 < turns.size() ? turns[i + 1].w.t_start_s : std::numeric_limits<double>::infinity();
    if (w.t_start_s < before_end)
      return make_error(at_turn(i, w) + ": starts before the turn before it has ended");
    if (std::isfinite(w.sample_before_s) &&
        !(w.sample_before_s <= w.t_start_s && w.sample_before_s > before_end))
      return make_error(at_turn(i, w) + ": its sample before the turn is not in the hold before");
    if (std::isfinite(w.sample_after_s) &&
        !(w.sample_after_s >= w.t_end_s && w.sample_after_s < after_start))
      return make_error(at_turn(i, w) + ": its sample after the turn is not in the hold after");
  }
  TimelineReport report;
  report.holds = holds_of(in, turns);
  const EarthAt e = EarthAt::at(in.site);
  const Nominal* nom = in.nominal ? &*in.nominal : nullptr;
  // a hold's transition over dt from t (about the nominal at its middle)
  const auto hold = [&](double psi_h, double t_h, double dt) {
    return discretize_hold(e, psi_h, dt, in.noise, nom, t_h + 0.5 * dt);
  };
  double psi = in.psi_start_rad;
  Discrete epoch = hold(psi, 0, in.epoch_s);
  double epoch_psi = psi;  // the orientation `epoch` is for
  double epoch_t = 0;      // and the time
  double t = 0;
  std::size_t next_turn = 0;
  for (const Mark& m : schedule(in, turns)) {
    TimelineStep step{t, m.t, &epoch, m.boundary};
    // the still interval around an epoch: from the last turn's end (or its
    // sample after) to the next turn's start (or its sample before)
    if (!m.boundary) {
      step.still_from_s = 0;
      step.still_to_s = in.duration_s + kSameTime;
      for (const ResolvedTurn& r : turns) {
        if (r.w.t_end_s <= m.t)
          step.still_from_s = std::isfinite(r.w.sample_after_s) ? r.w.sample_after_s : r.w.t_end_s;
        if (r.w.t_start_s > m.t) {
          step.still_to_s =
              std::isfinite(r.w.sample_before_s) ? r.w.sample_before_s : r.w.t_start_s;
          break;
        }
      }
    }
    const bool crosses = next_turn < turns.size() && turns[next_turn].w.t_start_s < m.t;
    if (!crosses && std::abs(m.t - t - in.epoch_s) < kSameTime) {
      // about a nominal, its state moves: each epoch its own transition
      if (psi != epoch_psi || (nom != nullptr && t != epoch_t)) {
        epoch = hold(psi, t, in.epoch_s);
        epoch_psi = psi;
        epoch_t = t;
      }
      fn(step);  // a whole epoch of hold
    } else {
      Discrete d;
      d.phi.setIdentity();
      d.q.setZero();
      while (next_turn < turns.size() && turns[next_turn].w.t_start_s < m.t) {
        const ResolvedTurn& r = turns[next_turn++];
        if (r.w.t_start_s - t > kSameTime) compose(d, hold(psi, t, r.w.t_start_s - t));
        compose(
            d, turn_transition(e, r.samples, in.noise,
                               r.source == TurnSource::ClosedForm ? &r.closed_form : nullptr, nom));
        report.turns.push_back(r.source);
        psi = r.samples.back().psi_rad;
        t = r.w.t_end_s;
      }
      if (m.t - t > kSameTime) compose(d, hold(psi, t, m.t - t));
      d.sqrt_q = psd_sqrt(d.q);
      step.d = &d;
      fn(step);
    }
    ++report.steps;
    t = m.t;
  }
  return report;
}

Result<std::vector<HoldSpan>> hold_spans(const TimelineInput& in) {
  TURNCAL_ASSIGN(turns, resolve_turns(in));
  return holds_of(in, turns);
}

double psi_at(std::span<const AngleSample> enc, double t) {
  auto it = std::lower_bound(enc.begin(), enc.end(), t,
                             [](const AngleSample& s, double v) { return s.t_s < v; });
  if (it == enc.begin()) return it->psi_rad;
  if (it == enc.end()) return enc.back().psi_rad;
  const AngleSample& b = *it;
  const AngleSample& a = *(it - 1);
  const double f = (t - a.t_s) / (b.t_s - a.t_s);
  return a.psi_rad + f * (b.psi_rad - a.psi_rad);
}

}  // namespace turncal::est
