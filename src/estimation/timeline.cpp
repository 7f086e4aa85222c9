#include "turncal/estimation/timeline.hpp"

#include <algorithm>
#include <cmath>

namespace turncal::est {
namespace {

/// Samples of the encoder within [t1, t2], with the end points interpolated.
std::vector<AngleSample> window_samples(std::span<const AngleSample> enc, double t1, double t2) {
  std::vector<AngleSample> out;
  auto interp = [&](double t) {
    auto it = std::lower_bound(enc.begin(), enc.end(), t,
                               [](const AngleSample& s, double v) { return s.t_s < v; });
    if (it == enc.begin()) return AngleSample{t, it->psi_rad};
    if (it == enc.end()) return AngleSample{t, enc.back().psi_rad};
    const AngleSample& b = *it;
    const AngleSample& a = *(it - 1);
    const double f = (t - a.t_s) / (b.t_s - a.t_s);
    return AngleSample{t, a.psi_rad + f * (b.psi_rad - a.psi_rad)};
  };
  out.push_back(interp(t1));
  for (const AngleSample& s : enc)
    if (s.t_s > t1 && s.t_s < t2) out.push_back(s);
  out.push_back(interp(t2));
  return out;
}

}  // namespace

void for_each_step(const TimelineInput& in, const std::function<void(const TimelineStep&)>& fn) {
  const EarthAt e = EarthAt::at(in.site);
  const auto n_epochs = static_cast<long>(std::floor(in.duration_s / in.epoch_s + 1e-9));
  std::size_t next_turn = 0;
  double psi_hold = in.psi_start_rad;
  Discrete hold = discretize_hold(e, psi_hold, in.epoch_s, in.noise);
  long k = 0;
  while (k < n_epochs) {
    const double t_from = static_cast<double>(k) * in.epoch_s;
    double t_to = static_cast<double>(k + 1) * in.epoch_s;
    if (next_turn < in.turns.size() && in.turns[next_turn].t_start_s < t_to) {
      // hold to the turn, the turn, hold to the first epoch after it
      const TurnWindow w = in.turns[next_turn++];
      long k_after = static_cast<long>(std::ceil(w.t_end_s / in.epoch_s - 1e-9));
      if (k_after <= k) k_after = k + 1;
      t_to = static_cast<double>(k_after) * in.epoch_s;
      const Discrete before = discretize_hold(e, psi_hold, w.t_start_s - t_from, in.noise);
      const auto samples = window_samples(in.encoder, w.t_start_s, w.t_end_s);
      const Discrete turn = turn_transition(e, samples, in.noise);
      psi_hold = samples.back().psi_rad;
      const Discrete after = discretize_hold(e, psi_hold, t_to - w.t_end_s, in.noise);
      Discrete d;
      d.phi = after.phi * turn.phi * before.phi;
      d.q = after.phi * (turn.phi * before.q * turn.phi.transpose() + turn.q) *
                after.phi.transpose() +
            after.q;
      d.sqrt_q = psd_sqrt(d.q);
      fn(TimelineStep{t_from, t_to, &d});
      hold = discretize_hold(e, psi_hold, in.epoch_s, in.noise);
      k = k_after;
      continue;
    }
    fn(TimelineStep{t_from, t_to, &hold});
    ++k;
  }
}

}  // namespace turncal::est
