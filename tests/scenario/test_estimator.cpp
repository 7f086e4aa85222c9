// What the estimator reports (model.md, 8): covariance analysis, the sharp
// combinations a turn determines, the two-stage baseline, the encoder-gap
// fallback of the turn (model.md, 7) and the innovation statistics.
#include <doctest/doctest.h>

#include <cmath>

#include "scenarios.hpp"

using namespace turncal;
using namespace scenario;

namespace {

constexpr std::size_t kIdx(int state_index) {
  return static_cast<std::size_t>(state_index - est::sx::kNu0);
}

est::EstimationInput plan(const Scenario& s, double psi_s, const Profile& profile) {
  const TableTrajectory table(profile);
  est::EstimationInput in;
  in.timeline = timeline(s, psi_s, table, encoder_of(table, profile.duration_s));
  in.priors = s.priors;
  in.sigma_z = s.sigma_z;
  return in;
}

/// The combination in which parameter j weighs most.
const est::Combination* led_by(const est::EstimationResult& r, std::size_t j) {
  const est::Combination* best = nullptr;
  double w = 0;
  for (const est::Combination& c : r.combinations) {
    const double cw = std::fabs(c.coeff[j]) * r.parameters[j].prior_sigma / c.prior_sigma;
    if (cw > w) {
      w = cw;
      best = &c;
    }
  }
  return best;
}

}  // namespace

TEST_SUITE("estimator") {
  TEST_CASE("covariance analysis gives the covariance the filter reaches on data") {
    // The covariance of a linear filter does not depend on the data: with a
    // velocity sample at every epoch the analysis must reproduce the run's P
    // (mean measurement, 100 Hz, so the analysis must also get sigma_z /
    // sqrt(100) right).
    est::EstimationInput in = plan(tactical(), 37 * kDeg, reference_profile());
    in.mean_measurement = true;
    in.sample_rate_hz = 100;
    std::mt19937_64 rng(3);
    std::normal_distribution<double> n(0, in.sigma_z);
    for (long k = 1; k <= 360000; ++k)
      in.velocity.push_back({static_cast<double>(k) / 100, n(rng), n(rng)});
    const auto a = est::analyse(in);
    const auto e = est::estimate(in);
    REQUIRE(a.ok());
    REQUIRE(e.ok());
    double worst = 0;
    for (int i = 0; i < est::sx::kN; ++i)
      for (int j = 0; j < est::sx::kN; ++j)
        worst = std::max(worst,
                         std::fabs(a->p(i, j) - e->p(i, j)) / std::sqrt(e->p(i, i) * e->p(j, j)));
    CHECK(worst < 1e-9);
    CHECK(a->x.isZero());
    CHECK(a->epoch_t.size() == e->epoch_t.size());
  }

  TEST_CASE(
      "one 180 deg turn: only df_eff - g theta_13 is sharp; a second turn sharpens r, not that "
      "tie") {
    // model.md, 8: the tilt jump of Theta_13 and the reversal of the
    // accelerometer bias look alike, so after one 180 deg turn (start
    // orientation 0: body axis 1 East) the run determines
    // df0_1 + g G13 - g Theta_13 much better than any of its terms.
    const Scenario s = tactical();
    const auto r = est::analyse(plan(s, 0, reference_profile()));
    REQUIRE(r.ok());
    const double g = est::EarthAt::at(s.site).g;
    for (int axis = 0; axis < 2; ++axis) {
      const std::size_t df = kIdx(est::sx::kDf0 + axis), gi3 = kIdx(est::sx::kG + axis),
                        th = kIdx(est::sx::theta(axis + 1, 3));
      const est::Combination* c = led_by(*r, gi3);
      REQUIRE(c != nullptr);
      const double k = c->coeff[df];  // normalize to df0_i: 1
      CAPTURE(axis);
      CHECK(c->coeff[gi3] / k == doctest::Approx(g).epsilon(0.01));
      CHECK(c->coeff[th] / k == doctest::Approx(-g).epsilon(0.01));
      // sharp: its sigma is a small part of its prior; its terms are not
      CHECK(c->sigma < 0.05 * c->prior_sigma);
      for (const std::size_t j : {df, gi3, th})
        CHECK(r->parameters[j].sigma > 0.7 * r->parameters[j].prior_sigma);
      CHECK(r->df_eff[static_cast<std::size_t>(axis)].sigma >
            0.5 * r->df_eff[static_cast<std::size_t>(axis)].prior_sigma);
    }
    // A second turn (config/profiles/tactical-two-turns.toml: on by 90 deg
    // at 2700 s) gives the proof-mass offset a
    // second jump to be seen in, but it cannot part df_eff from g Theta_.3:
    // for any turn about the vertical the tilt jump, -g [int A dpsi]
    // Theta_.3 through the dv rows, equals -g (A(psi2) - A(psi1)) Theta_.3,
    // the same signature as the bias change (A(psi2) - A(psi1)) df_eff.
    // Only a turn about another axis would part them.
    const Profile two = from_plan("tactical-two-turns.toml").profile;
    REQUIRE(two.turns.size() == 2);
    const auto r2 = est::analyse(plan(s, 0, two));
    REQUIRE(r2.ok());
    auto ratio = [](const est::ParameterEstimate& p) { return p.sigma / p.prior_sigma; };
    for (const int j : {est::sx::kR, est::sx::kR + 1}) {
      MESSAGE(r->parameters[kIdx(j)].name << ": sigma/prior " << ratio(r->parameters[kIdx(j)])
                                          << " with one turn, " << ratio(r2->parameters[kIdx(j)])
                                          << " with two");
      CHECK(r2->parameters[kIdx(j)].sigma < 0.8 * r->parameters[kIdx(j)].sigma);
    }
    for (int axis = 0; axis < 2; ++axis) {
      const auto& th1 = r->parameters[kIdx(est::sx::theta(axis + 1, 3))];
      const auto& th2 = r2->parameters[kIdx(est::sx::theta(axis + 1, 3))];
      const auto u = static_cast<std::size_t>(axis);
      MESSAGE(th1.name << ": sigma/prior " << ratio(th1) << " with one turn, " << ratio(th2)
                       << " with two; df_eff " << ratio(r->df_eff[u]) << ", "
                       << ratio(r2->df_eff[u]));
      CHECK(ratio(th2) == doctest::Approx(ratio(th1)).epsilon(0.01).scale(0));
      CHECK(ratio(r2->df_eff[u]) == doctest::Approx(ratio(r->df_eff[u])).epsilon(0.01).scale(0));
      const est::Combination* c = led_by(*r2, kIdx(est::sx::kG + axis));
      REQUIRE(c != nullptr);
      CHECK(c->sigma < 0.05 * c->prior_sigma);
    }
  }

  TEST_CASE("single loop is no worse than the two-stage baseline, to within 1%") {
    // model.md, 8: the re-alignment gives the two-stage method a sliver of
    // information the single loop lacks, hence the 1%.
    for (const Scenario& s : {tactical(), navigation_grade()})
      for (const double psi_s : {0.0, 37 * kDeg}) {
        est::EstimationInput in = plan(s, psi_s, reference_profile());
        in.with_two_stage = true;
        const auto r = est::analyse(in);
        REQUIRE(r.ok());
        REQUIRE(r->has_two_stage);
        double worst = 0;
        std::size_t worst_j = 0;
        for (std::size_t j = 0; j < est::kParamNames.size(); ++j) {
          CAPTURE(est::kParamNames[j]);
          CHECK(r->two_stage.ratio[j] <= 1.01);
          if (r->two_stage.ratio[j] > worst) worst = r->two_stage.ratio[worst_j = j];
        }
        MESSAGE("psi_s " << psi_s / kDeg << " deg: largest single/two-stage sigma ratio " << worst
                         << " (" << est::kParamNames[worst_j] << ")");
        // the proof-mass offset acts during the turn only: no hold sees it
        CHECK(r->two_stage.sigma[kIdx(est::sx::kR)] ==
              doctest::Approx(s.priors.params[kIdx(est::sx::kR)]).epsilon(1e-3).scale(0));
        CHECK(r->two_stage.ratio[kIdx(est::sx::kR)] < 0.2);
      }
  }

  TEST_CASE("the two-stage baseline beside the first pass gives what it gives after it") {
    // estimate() and analyse() start the baseline's holds on a thread of
    // their own (threads, 0 taken as the hardware's, above 1; 2 here); the
    // result must be the same, bit for bit,
    // as one thread's, and as two_stage() against the same covariance
    est::EstimationInput in = plan(tactical(), 37 * kDeg, reference_profile());
    in.with_two_stage = true;
    for (const bool analysed : {true, false}) {
      CAPTURE(analysed);
      auto once = [&](unsigned threads) {
        est::EstimationInput i = in;
        i.second_pass.threads = threads;
        return analysed ? est::analyse(i) : est::estimate(i);
      };
      const auto one = once(1), beside = once(2);
      REQUIRE(one.ok());
      REQUIRE(beside.ok());
      REQUIRE(one->has_two_stage);
      REQUIRE(beside->has_two_stage);
      const auto direct = est::two_stage(in, one->p);
      REQUIRE(direct.ok());
      int differ = 0;
      for (std::size_t j = 0; j < est::kParamNames.size(); ++j) {
        differ += beside->two_stage.sigma[j] != one->two_stage.sigma[j];
        differ += beside->two_stage.ratio[j] != one->two_stage.ratio[j];
        differ += direct->sigma[j] != one->two_stage.sigma[j];
        if (analysed) differ += direct->ratio[j] != one->two_stage.ratio[j];
      }
      CHECK(differ == 0);
      // it has something to compare: sigmas from the holds (the plan's
      // input has no velocity for estimate() to narrow r1 by)
      CHECK(one->two_stage.sigma[kIdx(est::sx::kNu0)] > 0);
      if (analysed) CHECK(one->two_stage.ratio[kIdx(est::sx::kR)] < 0.2);
    }
  }

  /// A simulated tactical run with no noise, errors at a tenth of the
  /// prior and the proof-mass offset at its full prior (a large turn jump),
  /// and how far the model's transitions, fed an encoder record, stray from
  /// its velocity in the minute after the turn.
  struct TurnCase {
    Scenario s = tactical();
    est::XiVec xi = xi_of();
    double psi_s = 37 * kDeg;
    sim::Config cfg = sim_config(xi, psi_s);
    sim::Run run = sim::simulate(cfg);
    TableTrajectory table{cfg.profile};
    est::EarthAt earth = est::EarthAt::at(s.site);

    static est::XiVec xi_of() {
      est::XiVec x = est::XiVec::Zero();
      x(est::sxi::kParams + kIdx(est::sx::kR)) = 0.03;
      x(est::sxi::kParams + kIdx(est::sx::kR) + 1) = -0.02;
      return x;
    }
    [[nodiscard]] est::TimelineInput full() const { return timeline(s, psi_s, table, run.encoder); }
    /// The worst velocity difference, m/s, and how the turn was taken.
    std::pair<double, est::TurnSource> stray(const est::TimelineInput& tl) const {
      est::StateVec x = est::initial_map(earth, psi_s) * xi;
      double worst = 0;
      auto rep = est::for_each_step(tl, [&](const est::TimelineStep& st) {
        x = st.d->phi * x;
        if (st.t_to < table.turn_end(0) || st.t_to > table.turn_end(0) + 60) return;
        const auto k = static_cast<std::size_t>(std::llround(st.t_to * cfg.output_rate_hz));
        const sim::VelocitySample& v = run.velocity[k];
        worst = std::max(worst, std::hypot(x(est::sx::kDv) - v.ve, x(est::sx::kDv + 1) - v.vn));
      });
      REQUIRE(rep.ok());
      REQUIRE(rep->turns.size() == 1);
      return {worst, rep->turns[0]};
    }
  };

  TEST_CASE("an encoder gap in the turn falls back to the constant-rate closed form") {
    // Given a simulated run (noise off, errors at a tenth of the tactical
    // prior, proof-mass offset at its full prior so the turn jump is large)
    // with the encoder silent through the whole turn, the model takes the
    // closed form: its velocity after the turn must still follow the
    // simulation, to the closed form's own error (model.md, 7: at 200 Hz
    // samples match the exact integrals to 1e-5; the plateau-rate formula
    // ignores the rate ramps, a few percent of Jc, Js).
    const TurnCase c;
    est::TimelineInput in = c.full();
    std::erase_if(in.encoder, [&](const est::AngleSample& a) {
      return a.t_s > c.table.turn_start(0) - 0.5 && a.t_s < c.table.turn_end(0) + 0.5;
    });
    const auto [worst, source] = c.stray(in);
    CHECK(source == est::TurnSource::ClosedForm);
    // the jump itself: |r| (Jc^2 + Js^2)^1/2 = |r| 2 Omega_bar for 180 deg
    const double jump = std::hypot(0.03, 0.02) * 2 * c.table.peak_rate(0);
    MESSAGE("closed form: worst velocity difference in the minute after the turn "
            << worst << " m/s of a " << jump << " m/s jump");
    CHECK(worst < 0.05 * jump);
    // with the samples the same comparison is tight
    const auto [worst_full, full_source] = c.stray(c.full());
    CHECK(full_source == est::TurnSource::Encoder);
    MESSAGE("encoder samples: worst difference " << worst_full << " m/s");
    CHECK(worst_full < 0.01 * jump);
    CHECK(worst_full < worst);
    // without a plan and without the encoder after the turn there is
    // nothing to go on: a clear error, not a guess
    est::TimelineInput blind = in;
    blind.turns[0].plateau_rate_rps = NAN;
    const auto none = est::for_each_step(blind, [](const est::TimelineStep&) {});
    REQUIRE_FALSE(none.ok());
    CHECK(none.error().message.find("plateau rate") != std::string::npos);
  }

  TEST_CASE("encoder gaps up to 0.25 s in the turn keep the samples, and cost next to nothing") {
    // The same simulated turn as above. The sample sums of Jc, Js tolerate
    // sparse samples (the rate is constant on the plateau, and a linear ramp
    // across a gap of g misses about alpha^2 g^3 / 12 of int Omega^2), so a
    // lost frame or two, or an encoder far slower than 200 Hz, must not
    // throw the turn onto the plateau-rate closed form, whose error is ten
    // times larger. Limits: a hole costs at most 1.5 times that ramp term
    // on top of the full-rate error (|r| alpha^2 g^3 / 12 = 6.6e-6 m/s for
    // 0.2 s; measured 7.3e-6 m/s on top of 9.3e-6), slower encoders 1.3
    // times the full-rate error, and a hole past 0.25 s goes to the closed
    // form.
    const TurnCase c;
    const double t1 = c.table.turn_start(0);
    auto with_hole = [&](double at, double g) {
      est::TimelineInput in = c.full();
      std::erase_if(in.encoder, [&](const est::AngleSample& a) {
        return a.t_s > t1 + at - 1e-9 && a.t_s < t1 + at + g;
      });
      return in;
    };
    const auto [full, full_source] = c.stray(c.full());
    REQUIRE(full_source == est::TurnSource::Encoder);
    // holes on the ramp up (0 and 0.5 s in) and on the plateau (3 s in)
    for (double at : {0.0, 0.5, 3.0})
      for (double g : {0.08, 0.2}) {
        CAPTURE(at);
        CAPTURE(g);
        const auto [w, source] = c.stray(with_hole(at, g));
        CHECK(source == est::TurnSource::Encoder);
        const double alpha = c.cfg.profile.turns[0].max_accel_rps2;
        const double ramp_miss = std::hypot(0.03, 0.02) * alpha * alpha * g * g * g / 12;
        CHECK(w < 1.05 * full + 1.5 * ramp_miss);
      }
    // the encoder at 25 Hz and at 5 Hz, with every sample on time
    for (std::size_t every : {8UL, 40UL}) {
      CAPTURE(every);
      est::TimelineInput in = c.full();
      std::vector<est::AngleSample> kept;
      for (std::size_t k = 0; k < in.encoder.size(); ++k)
        if (k % every == 0) kept.push_back(in.encoder[k]);
      in.encoder = kept;
      const auto [w, source] = c.stray(in);
      CHECK(source == est::TurnSource::Encoder);
      CHECK(w < 1.3 * full);
    }
    // past the limit: the closed form
    CHECK(c.stray(with_hole(0.5, 0.3)).second == est::TurnSource::ClosedForm);
  }

  TEST_CASE("innovations of a simulated run are white and consistent; a wrong noise shows") {
    // Given a navigation-grade run with sensor noise (fixed seed), the
    // normalized innovations pass the NIS 95% interval and the Ljung-Box
    // test at 20 lags (each a 5% false alarm rate by construction; the seed
    // is fixed). Declaring the velocity noise 3 times too small must fail
    // the consistency test.
    const Scenario s = navigation_grade();
    std::mt19937_64 rng(11);
    const est::XiVec xi = draw(s, rng);
    const double psi_s = 0;
    const sim::Config cfg = sim_config(s, xi, psi_s, 5);
    const sim::Run run = sim::simulate(cfg);
    const TableTrajectory table(cfg.profile);
    est::EstimationInput in;
    in.timeline = timeline(s, psi_s, table, run.encoder);
    in.priors = s.priors;
    in.sigma_z = s.sigma_z;
    for (const auto& v : run.velocity) in.velocity.push_back({v.t_s, v.ve, v.vn});
    const auto r = est::estimate(in);
    REQUIRE(r.ok());
    const est::InnovationStats& st = r->innovation_stats;
    MESSAGE("NIS mean " << st.nis_mean << " in [" << st.nis_lo << ", " << st.nis_hi
                        << "]; Ljung-Box " << st.ljung_box[0] << ", " << st.ljung_box[1]
                        << " limit " << st.ljung_box_limit);
    CHECK(st.count == r->innovations.size());
    CHECK(st.count > 3500);
    CHECK(st.consistent());
    CHECK(st.white());
    in.sigma_z = s.sigma_z / 3;
    const auto bad = est::estimate(in);
    REQUIRE(bad.ok());
    MESSAGE("declared noise 3x too small: NIS mean " << bad->innovation_stats.nis_mean);
    CHECK_FALSE(bad->innovation_stats.consistent());
  }
}

TEST_CASE("chi-square survival: exact and tabulated points") {
  using turncal::est::chi2_survival;
  // 2 degrees of freedom: exp(-x/2) exactly (relative tolerances: scale 0)
  for (const double x : {0.1, 1.0, 5.0, 20.0, 60.0})
    CHECK(chi2_survival(2, x) == doctest::Approx(std::exp(-x / 2)).epsilon(1e-9).scale(0));
  // the tables' upper points (to their five figures)
  CHECK(chi2_survival(1, 3.8415) == doctest::Approx(0.05).epsilon(1e-4).scale(0));
  CHECK(chi2_survival(10, 18.307) == doctest::Approx(0.05).epsilon(1e-4).scale(0));
  CHECK(chi2_survival(20, 45.315) == doctest::Approx(0.001).epsilon(1e-3).scale(0));
  CHECK(chi2_survival(30, 59.703) == doctest::Approx(0.001).epsilon(1e-3).scale(0));
  CHECK(chi2_survival(20, 10.851) == doctest::Approx(0.95).epsilon(1e-4).scale(0));
  CHECK(chi2_survival(5, 0) == 1.0);
  CHECK(std::isnan(chi2_survival(0, 1)));
}
