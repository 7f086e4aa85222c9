#include "turncal/estimation/estimator.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <future>
#include <memory>
#include <system_error>
#include <thread>

namespace turncal::est {
namespace {

using ParamVec = Eigen::Matrix<double, sx::kParams, 1>;
using ParamMat = Eigen::Matrix<double, sx::kParams, sx::kParams>;

/// The velocity samples with lo < t_s < hi.
std::pair<const VelocityObs*, const VelocityObs*> samples_in(const std::vector<VelocityObs>& v,
                                                             double lo, double hi) {
  auto first = std::upper_bound(v.begin(), v.end(), lo,
                                [](double x, const VelocityObs& o) { return x < o.t_s; });
  auto last = std::lower_bound(first, v.end(), hi,
                               [](const VelocityObs& o, double x) { return o.t_s < x; });
  return {v.data() + (first - v.begin()), v.data() + (last - v.begin())};
}

/// Where an epoch's measurement takes its samples from, an open interval:
/// within half an epoch of t (the sample on the far end belongs to the
/// epoch before, so adjacent windows share none) and inside the still
/// interval (whose ends are a turn or a boundary sample, used at its own
/// measurement); the mean's window centred on t (so the mean is where the
/// model evaluates it), shrunk to stay in the still interval. Empty when t
/// itself is not in the still interval.
std::pair<double, double> epoch_window(const EstimationInput& in, const TimelineStep& step) {
  constexpr double kShift =
      1e-6;  // s: a sample on an end is the earlier epoch's (samples are ms apart)
  const double t = step.t_to, half = 0.5 * in.timeline.epoch_s;
  if (!(t > step.still_from_s && t < step.still_to_s)) return {t, t};
  const double h =
      in.mean_measurement ? std::min({half, t - step.still_from_s, step.still_to_s - t}) : half;
  return {std::max(t - h + kShift, step.still_from_s), std::min(t + h + kShift, step.still_to_s)};
}

/// The measurement at the step's end: at a turn boundary the sample at
/// exactly that time; at an epoch the nearest sample in its window, or
/// the mean of the samples there.
bool measurement_at(const EstimationInput& in, const TimelineStep& step, Meas& z, double& sigma) {
  const auto& v = in.velocity;
  const double t = step.t_to;
  if (step.boundary) {
    auto [lo, hi] = samples_in(v, t - 1e-9, t + 1e-9);
    if (lo == hi) return false;
    z = Meas(lo->ve, lo->vn);
    sigma = in.sigma_z;
    return true;
  }
  const auto [from, to] = epoch_window(in, step);
  auto [lo, hi] = samples_in(v, from, to);
  if (lo == hi) return false;
  if (in.mean_measurement) {
    z.setZero();
    for (const VelocityObs* it = lo; it != hi; ++it) z += Meas(it->ve, it->vn);
    const auto n = static_cast<double>(hi - lo);
    z /= n;
    sigma = in.sigma_z / std::sqrt(n);
    return true;
  }
  const VelocityObs* best = lo;
  for (const VelocityObs* it = lo; it != hi; ++it)
    if (std::fabs(it->t_s - t) < std::fabs(best->t_s - t)) best = it;
  z = Meas(best->ve, best->vn);
  sigma = in.sigma_z;
  return true;
}

/// The measurement noise the covariance analysis assumes at the step's
/// end, with the samples on a grid of the INS rate from t0; false where
/// that grid has no sample for it.
bool planned_measurement(const EstimationInput& in, const TimelineStep& step, double& sigma) {
  sigma = in.sigma_z;
  if (step.boundary) return true;
  const double rate = in.sample_rate_hz;
  const auto [from, to] = epoch_window(in, step);
  // grid samples k / rate with from < k / rate < to
  const double k_lo = std::floor(from * rate + 1e-8);
  const double k_hi = std::ceil(to * rate - 1e-8) - 1;
  const double n = std::max(0.0, k_hi - k_lo);
  if (n < 1) return false;
  if (in.mean_measurement) sigma = in.sigma_z / std::sqrt(n);
  return true;
}

/// The turns' boundary samples (model.md, 5): the recorded INS samples, or
/// in a covariance analysis the grid of the INS rate from t0.
void boundary_samples(const EstimationInput& in, TimelineInput& tl, bool data) {
  const double rate = in.sample_rate_hz;
  for (std::size_t i = 0; i < tl.turns.size(); ++i) {
    TurnWindow& w = tl.turns[i];
    w.sample_before_s = w.sample_after_s = NAN;
    if (!in.boundary_measurements) continue;
    const double lo = i == 0 ? 0.0 : tl.turns[i - 1].t_end_s;
    const double hi = i + 1 < tl.turns.size() ? tl.turns[i + 1].t_start_s : tl.duration_s;
    double before = NAN, after = NAN;
    if (data) {
      const auto& v = in.velocity;
      auto b = std::upper_bound(v.begin(), v.end(), w.t_start_s,
                                [](double x, const VelocityObs& o) { return x < o.t_s; });
      if (b != v.begin()) before = (b - 1)->t_s;
      auto a = std::lower_bound(v.begin(), v.end(), w.t_end_s,
                                [](const VelocityObs& o, double x) { return o.t_s < x; });
      if (a != v.end()) after = a->t_s;
    } else if (rate > 0) {
      before = std::floor(w.t_start_s * rate + 1e-9) / rate;
      after = std::ceil(w.t_end_s * rate - 1e-9) / rate;
    }
    if (before > lo && before <= w.t_start_s) w.sample_before_s = before;
    if (after >= w.t_end_s && after < hi && after <= tl.duration_s) w.sample_after_s = after;
  }
}

/// The filter over `tl` from the alignment prior at tl.psi_start_rad (x0 =
/// T xi, xi of mean `prior_mean` and covariance Sigma_xi); with
/// data from in.velocity, or (covariance analysis) no data and the
/// measurements the INS rate's grid of samples gives.
Result<EstimationResult> run(const EstimationInput& in, const TimelineInput& given, bool data,
                             const XiVec& prior_mean = XiVec::Zero()) {
  if (!data && !(in.sample_rate_hz > 0))
    return make_error("the INS velocity rate must be positive for a covariance analysis");
  TimelineInput tl = given;
  boundary_samples(in, tl, data);
  if (!(in.sigma_z > 0)) return make_error("the velocity noise sigma must be positive");
  const EarthAt e = EarthAt::at(tl.site);
  const XiMat t = initial_map(e, tl.psi_start_rad);
  const XiVec sxi_diag = prior_sigmas(in.priors, tl.noise);
  const Eigen::Matrix<double, sx::kN, Eigen::Dynamic> s0 = t * sxi_diag.asDiagonal();
  // internal scaling: the prior sigma of each state
  SqrtFilter f(t * prior_mean, s0, s0.rowwise().norm());
  const MeasMat h = velocity_measurement();
  EstimationResult r;
  const std::size_t expected = static_cast<std::size_t>(tl.duration_s / tl.epoch_s) + 1;
  r.epoch_t.reserve(expected);
  r.x_history.reserve(expected);
  r.sigma_history.reserve(expected);
  if (data) r.innovations.reserve(expected);
  auto report = for_each_step(tl, [&](const TimelineStep& step) {
    f.predict(step.d->phi, step.d->sqrt_q);
    Meas z = Meas::Zero();
    double sigma = in.sigma_z;
    if (data ? measurement_at(in, step, z, sigma) : planned_measurement(in, step, sigma)) {
      const UpdateResult u = f.update(z, h, sigma);
      if (!u.ok) ++r.degraded_updates;
      if (data) r.innovations.push_back({step.t_to, u.innovation, u.innovation_cov});
    }
    r.epoch_t.push_back(step.t_to);
    r.x_history.push_back(f.state());
    r.sigma_history.push_back(f.sigma());
  });
  if (!report) return std::move(report).error();
  r.timeline = std::move(*report);
  r.x = f.state();
  r.p = f.covariance();
  return r;
}

ParamVec prior_params(const Priors& p) {
  return Eigen::Map<const ParamVec>(p.params.data());
}

/// chi^2 quantile with k degrees of freedom at the normal quantile z
/// (Wilson and Hilferty, 1931; good to a few 1e-3 relative for k >= 2).
double chi2_quantile(double k, double z) {
  const double a = 2.0 / (9.0 * k);
  const double c = 1.0 - a + z * std::sqrt(a);
  return k * c * c * c;
}

}  // namespace

/// Q(a, x) by its power series for P (x < a + 1) or its continued fraction
/// (modified Lentz), the standard pair of expansions of the incomplete
/// gamma function (Abramowitz and Stegun 6.5.29 and 6.5.31).
double chi2_survival(double k, double x) {
  if (!(k > 0) || std::isnan(x)) return NAN;
  if (x <= 0) return 1.0;
  const double a = k / 2, z = x / 2;
  const double log_front = a * std::log(z) - z - std::lgamma(a);
  constexpr int kMaxTerms = 10000;
  constexpr double kEps = 1e-15;
  if (z < a + 1) {
    double term = 1 / a, sum = term;
    for (int n = 1; n < kMaxTerms && std::abs(term) > kEps * std::abs(sum); ++n) {
      term *= z / (a + n);
      sum += term;
    }
    return std::clamp(1 - sum * std::exp(log_front), 0.0, 1.0);
  }
  constexpr double kTiny = 1e-300;
  double b = z + 1 - a, c = 1 / kTiny, d = 1 / b, h = d;
  for (int n = 1; n < kMaxTerms; ++n) {
    const double an = -n * (n - a);
    b += 2;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1 / d;
    const double step = d * c;
    h *= step;
    if (std::abs(step - 1) < kEps) break;
  }
  return std::clamp(std::exp(log_front) * h, 0.0, 1.0);
}

namespace {

constexpr double kZ975 = 1.959963984540054;
constexpr double kZ95 = 1.6448536269514722;

InnovationStats innovation_stats(const std::vector<Innovation>& innov, int lags) {
  InnovationStats s;
  std::vector<Eigen::Vector2d> e;
  e.reserve(innov.size());
  for (const Innovation& i : innov) {
    Eigen::LLT<Eigen::Matrix2d> llt(i.cov);
    if (llt.info() != Eigen::Success) continue;
    e.emplace_back(llt.matrixL().solve(i.value));
  }
  s.count = e.size();
  if (e.empty()) return s;
  const double n = static_cast<double>(e.size());
  double nis = 0;
  for (const auto& v : e) nis += v.squaredNorm();
  s.nis_mean = nis / n;
  s.nis_lo = chi2_quantile(2 * n, -kZ975) / n;
  s.nis_hi = chi2_quantile(2 * n, kZ975) / n;
  s.lags = std::clamp(lags, 1, std::max(1, static_cast<int>(e.size()) / 5));
  for (int c = 0; c < 2; ++c) {
    double c0 = 0;
    for (const auto& v : e) c0 += v(c) * v(c);
    double q = 0;
    for (int l = 1; l <= s.lags; ++l) {
      double cl = 0;
      for (std::size_t k = 0; k + static_cast<std::size_t>(l) < e.size(); ++k)
        cl += e[k](c) * e[k + static_cast<std::size_t>(l)](c);
      const double rho = c0 > 0 ? cl / c0 : 0;
      q += rho * rho / (n - l);
    }
    s.ljung_box[static_cast<std::size_t>(c)] = n * (n + 2) * q;
    s.ljung_box_p[static_cast<std::size_t>(c)] =
        chi2_survival(s.lags, s.ljung_box[static_cast<std::size_t>(c)]);
  }
  s.ljung_box_limit = chi2_quantile(s.lags, kZ95);
  return s;
}

/// Parameters, effective biases, correlation and sharp combinations from x, P.
/// df_eff_i = df0_i + g G_i3 as a linear form in the parameters.
ParamVec df_eff_direction(int i, double g) {
  ParamVec c = ParamVec::Zero();
  c(sx::kDf0 - sx::kNu0 + i) = 1;
  c(sx::kG - sx::kNu0 + i) = g;
  return c;
}
/// df_obs_i = df0_i + g G_i3 - g Theta_i3, what a vertical turn determines.
ParamVec df_obs_direction(int i, double g) {
  ParamVec c = df_eff_direction(i, g);
  c(sx::theta(i + 1, 3) - sx::kNu0) = -g;
  return c;
}

void interpret(const EstimationInput& in, EstimationResult& r) {
  const EarthAt e = EarthAt::at(in.timeline.site);
  const ParamVec x = r.x.segment<sx::kParams>(sx::kNu0);
  const ParamMat p = r.p.block<sx::kParams, sx::kParams>(sx::kNu0, sx::kNu0);
  const ParamVec prior = prior_params(in.priors);
  for (int j = 0; j < sx::kParams; ++j) {
    const auto u = static_cast<std::size_t>(j);
    r.parameters[u] = {kParamNames[u], kParamUnits[u], x(j), std::sqrt(std::max(0.0, p(j, j))),
                       prior(j)};
  }
  // the model's named combinations (model.md, 8)
  std::array<ParamVec, 2> obs_dir{};
  for (int i = 0; i < 2; ++i) {
    auto named = [&](std::string_view name, const ParamVec& v) {
      return ParameterEstimate{name, block_info(Block::kAccelBias).si_unit, v.dot(x),
                               std::sqrt(std::max(0.0, v.dot(p * v))),
                               v.cwiseProduct(prior).norm()};
    };
    r.df_eff[static_cast<std::size_t>(i)] =
        named(i == 0 ? "df_eff_1" : "df_eff_2", df_eff_direction(i, e.g));
    const ParamVec c = df_obs_direction(i, e.g);
    r.df_obs[static_cast<std::size_t>(i)] = named(i == 0 ? "df_obs_1" : "df_obs_2", c);
    obs_dir[static_cast<std::size_t>(i)] = c;
  }
  for (int i = 0; i < sx::kParams; ++i)
    for (int j = 0; j < sx::kParams; ++j) {
      const double d = std::sqrt(p(i, i) * p(j, j));
      r.correlation(i, j) = d > 0 ? p(i, j) / d : (i == j ? 1.0 : 0.0);
    }
  // Sharp combinations: eigenvectors of the prior-whitened posterior
  // D0^-1 P D0^-1 with small eigenvalues, over the parameters the prior
  // leaves free.
  std::vector<int> free;
  for (int j = 0; j < sx::kParams; ++j)
    if (prior(j) > 0) free.push_back(j);
  const auto m = static_cast<Eigen::Index>(free.size());
  Eigen::MatrixXd w(m, m);
  for (Eigen::Index a = 0; a < m; ++a)
    for (Eigen::Index b = 0; b < m; ++b) {
      const int i = free[static_cast<std::size_t>(a)], j = free[static_cast<std::size_t>(b)];
      w(a, b) = p(i, j) / (prior(i) * prior(j));
    }
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(w);
  // the sharp directions (ascending eigenvalues: sharpest first)
  Eigen::Index sharp = 0;
  while (sharp < m && std::sqrt(std::max(0.0, es.eigenvalues()(sharp))) <= in.sharp_ratio) ++sharp;
  Eigen::MatrixXd dirs = es.eigenvectors().leftCols(sharp);
  std::vector<bool> degenerate(static_cast<std::size_t>(sharp), false);
  // eigenvalues within 2% of each other: the directions of that eigenspace
  // are arbitrary mixtures; take instead the parameter axes it spans most,
  // projected onto it and orthonormalised in that order
  for (Eigen::Index k = 0; k < sharp;) {
    Eigen::Index end = k + 1;
    while (end < sharp && es.eigenvalues()(end) <= 1.02 * es.eigenvalues()(k)) ++end;
    const Eigen::Index n = end - k;
    if (n > 1) {
      // at each step the parameter axis whose projection onto the space,
      // less the directions already taken, is longest (pivoted
      // Gram-Schmidt): never a near-zero vector normalised
      const Eigen::MatrixXd span = es.eigenvectors().middleCols(k, n);
      Eigen::MatrixXd taken(m, n);
      Eigen::Index got = 0;
      for (; got < n; ++got) {
        Eigen::VectorXd best;
        double best_norm = 0;
        for (Eigen::Index a = 0; a < m; ++a) {
          Eigen::VectorXd v = span * span.row(a).transpose();
          for (Eigen::Index o = 0; o < got; ++o) v -= taken.col(o).dot(v) * taken.col(o);
          if (v.norm() > best_norm) {
            best_norm = v.norm();
            best = v;
          }
        }
        if (best_norm < 1e-6) break;
        taken.col(got) = best / best_norm;
      }
      if (got == n) {  // else the eigenvectors stay: no cleaner basis found
        for (Eigen::Index q = 0; q < n; ++q) {
          dirs.col(k + q) = taken.col(q);
          degenerate[static_cast<std::size_t>(k + q)] = true;
        }
      }
    }
    k = end;
  }
  r.combinations.clear();
  for (Eigen::Index k = 0; k < sharp; ++k) {
    const Eigen::VectorXd v = dirs.col(k);
    const double ratio = std::sqrt(std::max(0.0, v.dot(w * v)));
    Eigen::Index lead_k = 0;
    v.cwiseAbs().maxCoeff(&lead_k);
    Combination c;
    c.from_degenerate = degenerate[static_cast<std::size_t>(k)];
    c.lead = free[static_cast<std::size_t>(lead_k)];
    const double scale = v(lead_k) / prior(c.lead);  // coefficient of lead before scaling
    for (Eigen::Index a = 0; a < m; ++a) {
      const int j = free[static_cast<std::size_t>(a)];
      c.coeff[static_cast<std::size_t>(j)] = a == lead_k ? 1.0 : v(a) / prior(j) / scale;
    }
    ParamVec cv = Eigen::Map<const ParamVec>(c.coeff.data());
    c.value = cv.dot(x);
    c.prior_sigma = prior(c.lead) / std::fabs(v(lead_k));
    c.sigma = ratio * c.prior_sigma;
    // one of the model's named combinations? When the direction, scaled to
    // df0_i's coefficient 1, has the named one's coefficients on its terms
    // (to 10%) and the named combination alone is determined as well (its
    // own posterior sigma within 25% of the direction's, either way): the
    // other terms are ones the run determines apart, and the name is what
    // it measured. Each name once, for the sharpest such direction.
    for (std::size_t i = 0; i < 2; ++i) {
      const int df = sx::kDf0 - sx::kNu0 + static_cast<int>(i);
      const double at_df = cv(df);
      if (at_df == 0 || r.df_obs[i].prior_sigma <= 0 || !c.name.empty()) continue;
      if (std::any_of(r.combinations.begin(), r.combinations.end(),
                      [&](const Combination& o) { return o.name == r.df_obs[i].name; }))
        continue;
      bool same = true;
      for (int j = 0; j < sx::kParams; ++j)
        if (obs_dir[i](j) != 0)
          same = same && std::abs(cv(j) / at_df - obs_dir[i](j)) <= 0.1 * std::abs(obs_dir[i](j));
      const double sigma_scaled =
          c.sigma * std::abs(c.coeff[static_cast<std::size_t>(c.lead)]) / std::abs(at_df);
      if (same && r.df_obs[i].sigma <= 1.25 * sigma_scaled &&
          r.df_obs[i].sigma >= 0.8 * sigma_scaled) {
        c.name = r.df_obs[i].name;
        c.from_degenerate = false;  // the model's own combination: no basis chosen
        c.coeff = {};
        for (int j = 0; j < sx::kParams; ++j) c.coeff[static_cast<std::size_t>(j)] = obs_dir[i](j);
        c.lead = sx::kDf0 - sx::kNu0 + static_cast<int>(i);
        c.value = r.df_obs[i].value;
        c.sigma = r.df_obs[i].sigma;
        c.prior_sigma = r.df_obs[i].prior_sigma;
      }
    }
    r.combinations.push_back(c);
  }
}

}  // namespace

XiVec prior_sigmas(const Priors& pr, const ProcessNoise& noise) {
  XiVec s = XiVec::Zero();
  s(sxi::kV0) = s(sxi::kV0 + 1) = pr.v0_mps;
  s(sxi::kDrE) = s(sxi::kDrN) = pr.position_m;
  s(sxi::kDpsi0) = pr.heading_rad;
  s(sxi::kNbar) = s(sxi::kNbar + 1) = pr.align_s > 0 ? std::sqrt(noise.q_a / pr.align_s) : 0.0;
  for (int p = 0; p < sx::kParams; ++p)
    s(sxi::kParams + p) = pr.params[static_cast<std::size_t>(p)];
  return s;
}

namespace {

using ParamArray = std::array<double, sx::kParams>;

/// The nominal's velocity at t (see sample_at).
Meas nominal_at(const std::vector<VelocityObs>& nom, double t, std::size_t& k) {
  const VelocityObs v =
      sample_at(nom, t, k, [](const VelocityObs& a, const VelocityObs& b, double f) {
        return VelocityObs{0, a.ve + f * (b.ve - a.ve), a.vn + f * (b.vn - a.vn)};
      });
  return Meas(v.ve, v.vn);
}

/// One iteration of the second pass about `p`: the filter on z - h(p)
/// with the parameters' prior mean at -p, its estimate and history put
/// back in parameter terms (p + correction, dv of the nominal plus
/// correction).
Result<EstimationResult> pass_about(const EstimationInput& in, const ParamArray& p) {
  TURNCAL_ASSIGN(run_about, in.second_pass.nominal(in, p));
  const std::vector<VelocityObs>& nom = run_about.velocity;
  if (nom.empty()) return make_error("the nonlinear nominal gave no velocity");
  // a track that does not start at t0 the timeline refuses, naming it
  EstimationInput resid = in;
  // the model linearised about the nominal (model.md, 8)
  resid.timeline.nominal =
      Nominal{p, std::make_shared<const std::vector<NominalState>>(std::move(run_about.track))};
  std::size_t k = 0;
  for (VelocityObs& v : resid.velocity) {
    const Meas h = nominal_at(nom, v.t_s, k);
    v.ve -= h(0);
    v.vn -= h(1);
  }
  XiVec mean = XiVec::Zero();
  for (int j = 0; j < sx::kParams; ++j) mean(sxi::kParams + j) = -p[static_cast<std::size_t>(j)];
  TURNCAL_ASSIGN(r, run(resid, resid.timeline, true, mean));
  // a NaN would pass the iteration's test of its change as none at all
  if (!r.x.allFinite() || !r.p.allFinite())
    return make_error("the pass about the nominal gave an estimate that is not finite");
  const ParamVec pv = Eigen::Map<const ParamVec>(p.data());
  r.x.segment<sx::kParams>(sx::kNu0) += pv;
  k = 0;
  for (std::size_t i = 0; i < r.x_history.size(); ++i) {
    r.x_history[i].segment<sx::kParams>(sx::kNu0) += pv;
    r.x_history[i].segment<2>(sx::kDv) += nominal_at(nom, r.epoch_t[i], k);
  }
  r.x.segment<2>(sx::kDv) += nominal_at(nom, in.timeline.duration_s, k);
  return r;
}

ParamArray params_of(const StateVec& x) {
  ParamArray p{};
  for (int j = 0; j < sx::kParams; ++j) p[static_cast<std::size_t>(j)] = x(sx::kNu0 + j);
  return p;
}

std::string fixed(double v, int digits) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", digits, v);
  return buf;
}

/// The largest angle the table turned from its start orientation, rad.
double largest_turn_rad(const TimelineInput& tl) {
  double turned = 0;
  for (const AngleSample& a : tl.encoder)
    if (a.t_s >= 0 && a.t_s <= tl.duration_s)
      turned = std::max(turned, std::abs(a.psi_rad - tl.psi_start_rad));
  return turned;
}

}  // namespace

double linearisation_error_sigma(const EstimationInput& in, const EstimationResult& first) {
  const TimelineInput& tl = in.timeline;
  const EarthAt e = EarthAt::at(tl.site);
  const auto est = [&](int state) {
    const auto j = static_cast<std::size_t>(state - sx::kNu0);
    return std::abs(first.parameters[j].value) + first.parameters[j].sigma;
  };
  const double b3 = in.priors.heading_rad + est(sx::kNu0 + 2) * tl.duration_s +
                    est(sx::theta(3, 3)) * largest_turn_rad(tl);
  // the largest speed: the sample of the largest square found first (a
  // libm hypot a sample took 20 ms on two hours), then its hypot alone
  double v2_max = -1;
  const VelocityObs* fastest = nullptr;
  for (const VelocityObs& v : in.velocity)
    if (const double v2 = v.ve * v.ve + v.vn * v.vn; v2 > v2_max) {
      v2_max = v2;
      fastest = &v;
    }
  const double v_max = fastest != nullptr ? std::hypot(fastest->ve, fastest->vn) : 0.0;
  const double rho = b3 + v_max / std::sqrt(e.g * std::sqrt(e.rm * e.rn));
  double worst = 0;
  const auto take = [&](const ParameterEstimate& q) {
    if (q.sigma > 0 && q.prior_sigma > 0 && q.sigma < 0.5 * q.prior_sigma)
      worst = std::max(worst, std::abs(q.value) / q.sigma);
  };
  for (const ParameterEstimate& q : first.parameters) take(q);
  for (const ParameterEstimate& q : first.df_obs) take(q);
  return rho * worst;
}

namespace {

Result<TwoStage> two_stage_sigmas(const EstimationInput& in);
TwoStage compared(TwoStage ts, const StateMat& single_p);

/// The two-stage baseline, where the input asks for it: its holds' runs
/// need nothing of the single-loop filter's, so they start on a thread of
/// their own beside the caller's passes (where `threads` allows more than
/// one, and a thread can be had) and are compared with its covariance when
/// taken. Its result and any exception come out of `take` as they would
/// have from a call there; a baseline not taken is waited for when this is
/// destroyed (it reads the input).
class Baseline {
 public:
  explicit Baseline(const EstimationInput& in) : in_(in) {
    const unsigned threads =
        in.second_pass.threads != 0 ? in.second_pass.threads : std::thread::hardware_concurrency();
    if (!in.with_two_stage || threads <= 1) return;
    try {
      sigmas_ = std::async(std::launch::async, [&in] { return two_stage_sigmas(in); });
    } catch (const std::system_error&) {  // no thread: taken where it is asked for
    }
  }
  Baseline(const Baseline&) = delete;
  Baseline& operator=(const Baseline&) = delete;
  ~Baseline() {
    if (sigmas_.valid()) sigmas_.wait();
  }
  /// Sets r's two-stage result against the covariance `single_p`.
  Status take(EstimationResult& r, const StateMat& single_p) {
    if (!in_.with_two_stage) return Status{Ok{}};
    auto ts = sigmas_.valid() ? sigmas_.get() : two_stage_sigmas(in_);
    if (!ts) return std::move(ts).error();
    r.two_stage = compared(*ts, single_p);
    r.has_two_stage = true;
    return Status{Ok{}};
  }

 private:
  const EstimationInput& in_;
  std::future<Result<TwoStage>> sigmas_;
};

}  // namespace

Result<EstimationResult> estimate(const EstimationInput& in) {
  Baseline baseline(in);
  TURNCAL_ASSIGN(r, run(in, in.timeline, true));
  interpret(in, r);
  const SecondPassSettings& sp = in.second_pass;
  SecondPass pass;
  pass.predicted_sigma = linearisation_error_sigma(in, r);
  const std::string predicted = "the first pass predicts a linearisation error of " +
                                fixed(pass.predicted_sigma, 2) + " sigma (threshold " +
                                fixed(sp.threshold_sigma, 2) + ")";
  if (sp.mode == SecondPassSettings::Mode::Off) {
    pass.reason = "turned off; " + predicted;
  } else if (sp.nominal == nullptr) {
    pass.reason = "no nonlinear nominal given; " + predicted;
  } else if (sp.mode == SecondPassSettings::Mode::Auto &&
             !(pass.predicted_sigma > sp.threshold_sigma)) {
    pass.reason = predicted + ": the linear model suffices";
  } else {
    pass.reason =
        sp.mode == SecondPassSettings::Mode::Always ? "asked for; " + predicted : predicted;
    ParamArray p = params_of(r.x);
    const EstimationResult first = r;
    double previous_change = INFINITY;
    while (pass.iterations < std::max(1, sp.max_iterations)) {
      auto next = pass_about(in, p);
      if (!next) {  // the first pass, or the last iteration, stands
        pass.reason += "; stopped after " + std::to_string(pass.iterations) +
                       " iterations: " + next.error().describe();
        break;
      }
      EstimationResult ri = std::move(next).value();
      ++pass.iterations;
      // the change of this iteration, p_{i+1} - p_i, in the sigmas of this
      // linearisation (fixed parameters, sigma 0, never move)
      double change = 0;
      for (int j = 0; j < sx::kParams; ++j) {
        const double sigma = std::sqrt(std::max(0.0, ri.p(sx::kNu0 + j, sx::kNu0 + j)));
        const double d = ri.x(sx::kNu0 + j) - p[static_cast<std::size_t>(j)];
        if (sigma > 0) change = std::max(change, std::abs(d) / sigma);
      }
      pass.last_change_sigma = change;
      // a change of half a sigma or more that grows is an iteration that
      // diverges: what it gives is no estimate, and the first pass stands
      // (said in the reason). Changes that wander near the tolerance are
      // the linearisation's floor, not a divergence.
      if (change > previous_change && change >= 0.5) {
        pass.reason += "; it diverged (the change grew from " + fixed(previous_change, 3) + " to " +
                       fixed(change, 3) + " sigma at iteration " + std::to_string(pass.iterations) +
                       "): the first pass's estimates stand";
        r = first;
        pass.iterations = 0;
        break;
      }
      previous_change = change;
      p = params_of(ri.x);
      r = std::move(ri);
      if (change < sp.tolerance_sigma) {
        pass.converged = true;
        break;
      }
    }
    pass.ran = pass.iterations > 0;
    if (pass.ran) interpret(in, r);
  }
  r.second_pass = pass;
  r.innovation_stats = innovation_stats(r.innovations, in.whiteness_lags);
  TURNCAL_TRY(baseline.take(r, r.p));
  return r;
}

Result<EstimationResult> analyse(const EstimationInput& in) {
  Baseline baseline(in);
  TURNCAL_ASSIGN(r, run(in, in.timeline, false));
  interpret(in, r);
  TURNCAL_TRY(baseline.take(r, r.p));
  return r;
}

namespace {

/// The two-stage baseline's sigmas (TwoStage::sigma; the ratios are left
/// to `compared`): each hold's own run, nothing of the single-loop filter's.
Result<TwoStage> two_stage_sigmas(const EstimationInput& in) {
  TURNCAL_ASSIGN(holds, hold_spans(in.timeline));
  const ParamVec prior = prior_params(in.priors);
  ParamVec d = prior;
  for (int j = 0; j < sx::kParams; ++j)
    if (!(d(j) > 0)) d(j) = 1;  // fixed parameters: no information, kept out below
  // Whitened information: I = sum_h W_h^-1 - (H - 1) I, W_h = D0^-1 P_h D0^-1.
  ParamMat info = ParamMat::Zero();
  int used = 0;
  for (const HoldSpan& hold : holds) {
    TimelineInput tl = in.timeline;
    tl.duration_s = hold.t_to_s - hold.t_from_s;
    if (tl.duration_s < tl.epoch_s) continue;
    tl.psi_start_rad = hold.psi_rad;
    tl.turns.clear();
    tl.encoder.clear();
    TURNCAL_ASSIGN(r, run(in, tl, false));
    ParamMat w = d.cwiseInverse().asDiagonal() *
                 r.p.block<sx::kParams, sx::kParams>(sx::kNu0, sx::kNu0) *
                 d.cwiseInverse().asDiagonal();
    for (int j = 0; j < sx::kParams; ++j)
      if (!(prior(j) > 0)) {
        w.row(j).setZero();
        w.col(j).setZero();
        w(j, j) = 1;
      }
    info += w.ldlt().solve(ParamMat::Identity());
    ++used;
  }
  if (used == 0) return make_error("the two-stage baseline needs at least one hold of an epoch");
  info -= static_cast<double>(used - 1) * ParamMat::Identity();
  const ParamMat pw = info.ldlt().solve(ParamMat::Identity());
  TwoStage ts;
  for (int j = 0; j < sx::kParams; ++j)
    ts.sigma[static_cast<std::size_t>(j)] =
        prior(j) > 0 ? d(j) * std::sqrt(std::max(0.0, pw(j, j))) : 0.0;
  return ts;
}

/// The baseline's sigmas with their ratios to the single-loop filter's.
TwoStage compared(TwoStage ts, const StateMat& single_p) {
  for (int j = 0; j < sx::kParams; ++j) {
    const auto u = static_cast<std::size_t>(j);
    const double single = std::sqrt(std::max(0.0, single_p(sx::kNu0 + j, sx::kNu0 + j)));
    ts.ratio[u] = ts.sigma[u] > 0 ? single / ts.sigma[u] : 1.0;
  }
  return ts;
}

}  // namespace

Result<TwoStage> two_stage(const EstimationInput& in, const StateMat& single_p) {
  TURNCAL_ASSIGN(ts, two_stage_sigmas(in));
  return compared(ts, single_p);
}

}  // namespace turncal::est
