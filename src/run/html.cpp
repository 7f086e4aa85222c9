#include "turncal/run/html.hpp"

#include "turncal/run/calibration.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <string_view>
#include <utility>
#include <vector>

#include "text_format.hpp"
#include "turncal/config.hpp"
#include "turncal/run/report.hpp"
#include "turncal/run/thin.hpp"

namespace turncal::run {

using detail::fmt;
using nlohmann::json;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kRadToDeg = 180 / std::numbers::pi;

std::string escape(std::string_view s) {
  std::string out;
  out.reserve(s.size());
  for (const char c : s) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

struct Series {
  std::string name;
  std::string color;
  std::vector<double> x, y;
};

struct Span {
  double from, to;
};

// plot geometry, in SVG units
constexpr double kW = 760, kH = 260, kL = 70, kR = 16, kT = 28, kB = 42;
constexpr double kPlotW = kW - kL - kR, kPlotH = kH - kT - kB;

/// A line chart in SVG. Long series are thinned to at most two points (the
/// lowest and the highest) per half-pixel column, so a one-hour 100 Hz
/// record draws as what it is without a megabyte of path; a series thinned
/// before on the same axis draws the same.
class Plot {
 public:
  Plot(std::string title, std::string x_label, std::string y_label, bool log_y = false)
      : title_(std::move(title)),
        x_label_(std::move(x_label)),
        y_label_(std::move(y_label)),
        log_y_(log_y) {}
  void add(Series s) { series_.push_back(std::move(s)); }
  void mark(const std::vector<Span>& spans) { spans_ = spans; }
  /// Bars instead of lines for series 0 (a histogram: x are bin centres).
  void bars() { bars_ = true; }

  [[nodiscard]] std::string svg() const;
  /// The x axis of points spanning [x0, x1] (one unit wide if they do not
  /// span): what a series can be thinned on before it is added.
  [[nodiscard]] static Axis axis(double x0, double x1) {
    return {x0, x1 == x0 ? x0 + 1 : x1, kL, kPlotW};
  }

 private:
  [[nodiscard]] double ty(double v) const { return log_y_ ? std::log10(v) : v; }
  std::string title_, x_label_, y_label_;
  bool log_y_ = false;
  bool bars_ = false;
  std::vector<Series> series_;
  std::vector<Span> spans_;
};

/// Ticks at 1, 2 or 5 times a power of ten, about `n` of them.
std::vector<double> nice_ticks(double lo, double hi, int n) {
  std::vector<double> out;
  if (!(hi > lo)) return out;
  const double raw = (hi - lo) / n;
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  double step = p;
  for (const double m : {1.0, 2.0, 5.0, 10.0})
    if (m * p >= raw) {
      step = m * p;
      break;
    }
  for (double v = std::ceil(lo / step) * step; v <= hi + step * 1e-9; v += step)
    out.push_back(std::abs(v) < step * 1e-9 ? 0 : v);
  return out;
}

std::string Plot::svg() const {
  const double pw = kPlotW, ph = kPlotH;
  double x0 = std::numeric_limits<double>::infinity(), x1 = -x0, y0 = x0, y1 = -x0;
  for (const Series& s : series_)
    for (std::size_t i = 0; i < s.x.size(); ++i) {
      if (!std::isfinite(s.y[i]) || (log_y_ && s.y[i] <= 0)) continue;
      x0 = std::min(x0, s.x[i]);
      x1 = std::max(x1, s.x[i]);
      y0 = std::min(y0, ty(s.y[i]));
      y1 = std::max(y1, ty(s.y[i]));
    }
  std::string o =
      "<figure class=\"plot\"><svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 " +
      fmt("%.0f", kW) + " " + fmt("%.0f", kH) + "\" role=\"img\" aria-label=\"" + escape(title_) +
      "\">";
  o += "<text class=\"title\" x=\"" + fmt("%.0f", kL) + "\" y=\"18\">" + escape(title_) + "</text>";
  if (!(x1 >= x0) || !(y1 >= y0)) {
    o += "<text x=\"" + fmt("%.0f", kW / 2) + "\" y=\"" + fmt("%.0f", kH / 2) +
         "\" text-anchor=\"middle\">no data</text></svg></figure>\n";
    return o;
  }
  if (bars_ || !log_y_) y0 = std::min(y0, bars_ ? 0.0 : y0);
  if (y1 - y0 < 1e-12 * std::max(1.0, std::abs(y1))) {
    y0 -= 1;
    y1 += 1;
  }
  const double pad = (y1 - y0) * 0.05;
  y0 -= bars_ ? 0 : pad;
  y1 += pad;
  const Axis axis = Plot::axis(x0, x1);
  x1 = axis.x1;
  auto px = [&](double x) { return kL + (x - x0) / (x1 - x0) * pw; };
  auto py = [&](double y) { return kT + (1 - (ty(y) - y0) / (y1 - y0)) * ph; };
  // what the script needs to read values under the pointer
  o.insert(o.find("<svg ") + 5, "data-x0=\"" + fmt("%.9g", x0) + "\" data-x1=\"" + fmt("%.9g", x1) +
                                    "\" data-y0=\"" + fmt("%.9g", y0) + "\" data-y1=\"" +
                                    fmt("%.9g", y1) + "\" data-log=\"" + (log_y_ ? "1" : "0") +
                                    "\" ");
  for (const Span& s : spans_)
    o += "<rect class=\"turn\" x=\"" + fmt("%.1f", px(std::max(s.from, x0))) + "\" y=\"" +
         fmt("%.0f", kT) + "\" width=\"" +
         fmt("%.1f", std::max(1.0, px(std::min(s.to, x1)) - px(std::max(s.from, x0)))) +
         "\" height=\"" + fmt("%.0f", ph) + "\"><title>turn</title></rect>";
  // axes and grid
  for (const double t : nice_ticks(x0, x1, 8)) {
    const double x = px(t);
    o += "<line class=\"grid\" x1=\"" + fmt("%.1f", x) + "\" x2=\"" + fmt("%.1f", x) + "\" y1=\"" +
         fmt("%.0f", kT) + "\" y2=\"" + fmt("%.0f", kT + ph) + "\"/>";
    o += "<text class=\"tick\" x=\"" + fmt("%.1f", x) + "\" y=\"" + fmt("%.0f", kT + ph + 14) +
         "\" text-anchor=\"middle\">" + fmt("%g", t) + "</text>";
  }
  std::vector<double> yt;
  if (log_y_) {
    for (double e = std::floor(y0); e <= y1; e += 1)
      if (e >= y0) yt.push_back(e);
  } else {
    yt = nice_ticks(y0, y1, 5);
  }
  for (const double t : yt) {
    const double y = kT + (1 - (t - y0) / (y1 - y0)) * ph;
    o += "<line class=\"grid\" x1=\"" + fmt("%.0f", kL) + "\" x2=\"" + fmt("%.0f", kL + pw) +
         "\" y1=\"" + fmt("%.1f", y) + "\" y2=\"" + fmt("%.1f", y) + "\"/>";
    o += "<text class=\"tick\" x=\"" + fmt("%.0f", kL - 4) + "\" y=\"" + fmt("%.1f", y + 4) +
         "\" text-anchor=\"end\">" + (log_y_ ? fmt("%g", std::pow(10.0, t)) : fmt("%g", t)) +
         "</text>";
  }
  o += "<rect class=\"frame\" x=\"" + fmt("%.0f", kL) + "\" y=\"" + fmt("%.0f", kT) +
       "\" width=\"" + fmt("%.0f", pw) + "\" height=\"" + fmt("%.0f", ph) + "\"/>";
  o += "<text class=\"label\" x=\"" + fmt("%.0f", kL + pw / 2) + "\" y=\"" + fmt("%.0f", kH - 6) +
       "\" text-anchor=\"middle\">" + escape(x_label_) + "</text>";
  o += "<text class=\"label\" transform=\"translate(14," + fmt("%.0f", kT + ph / 2) +
       ") rotate(-90)\" text-anchor=\"middle\">" + escape(y_label_) + "</text>";
  // the series
  double legend_x = kL + pw;
  for (std::size_t k = series_.size(); k-- > 0;) {
    const Series& s = series_[k];
    if (bars_ && k == 0) {
      const double w = s.x.size() > 1 ? px(s.x[1]) - px(s.x[0]) : pw;
      for (std::size_t i = 0; i < s.x.size(); ++i)
        o += "<rect class=\"bar\" x=\"" + fmt("%.1f", px(s.x[i]) - w / 2) + "\" y=\"" +
             fmt("%.1f", py(s.y[i])) + "\" width=\"" + fmt("%.1f", std::max(0.5, w - 1)) +
             "\" height=\"" + fmt("%.1f", std::max(0.0, kT + ph - py(s.y[i]))) + "\" fill=\"" +
             s.color + "\"/>";
    } else {
      // at most the lowest and highest point per half-pixel column, and the ends
      Thinned thin(axis);
      for (std::size_t i = 0; i < s.x.size(); ++i)
        if (!log_y_ || s.y[i] > 0) thin.add(s.x[i], s.y[i]);
      const auto [xs, ys] = thin.take();
      std::string d;
      for (std::size_t i = 0; i < xs.size(); ++i)
        d += (i == 0 ? "M" : "L") + fmt("%.1f", px(xs[i])) + "," + fmt("%.1f", py(ys[i]));
      o += "<path class=\"line\" stroke=\"" + s.color + "\" d=\"" + d + "\"/>";
    }
    if (!s.name.empty()) {
      legend_x -= 8.0 + 7.0 * static_cast<double>(s.name.size());
      o += "<text class=\"legend\" x=\"" + fmt("%.0f", legend_x) + "\" y=\"18\" fill=\"" + s.color +
           "\">" + escape(s.name) + "</text>";
    }
  }
  o += "<text class=\"readout\" x=\"" + fmt("%.0f", kL + 6) + "\" y=\"" + fmt("%.0f", kT + 14) +
       "\"></text></svg></figure>\n";
  return o;
}

constexpr std::array<const char*, 6> kColors = {"#1f77b4", "#d62728", "#2ca02c",
                                                "#9467bd", "#ff7f0e", "#8c564b"};

}  // namespace

const std::vector<SigmaPlotGroup>& sigma_plot_groups() {
  // a plot per block of the parameter table
  static const std::vector<SigmaPlotGroup> g = [] {
    std::vector<SigmaPlotGroup> out;
    for (const est::BlockInfo& b : est::kBlocks) {
      SigmaPlotGroup p{std::string(b.title) + ": sigma against time", {}};
      for (int i = 0; i < b.size; ++i) p.params.push_back(est::block_offset(b.block) + i);
      out.push_back(std::move(p));
    }
    return out;
  }();
  return g;
}

namespace {

std::string number(double v, const char* f = "%.6g") {
  return std::isfinite(v) ? fmt(f, v) : std::string("-");
}

std::string parameter_table(const json& r) {
  if (!r.contains("estimates")) return "";
  // pass/fail per parameter, from the verdict
  json verdict = json::object();
  for (const auto& c : r["verdict"].value("checks", json::array()))
    verdict[c.value("parameter", std::string())] =
        c.value("tested", true) ? json(c.value("pass", false)) : json("not tested");
  std::string o =
      "<h2>Parameters</h2><table class=\"params\"><thead><tr><th>parameter</th><th>estimate</th>"
      "<th>sigma</th><th>prior sigma</th><th>posterior/prior</th><th>unit</th><th>tolerance</th>"
      "</tr></thead><tbody>";
  for (const auto& [name, e] : r["estimates"].items()) {
    const auto [unit, k] = display_unit(name);
    const double s = e["sigma"].get<double>(), p = e["prior_sigma"].get<double>();
    const double ratio = p > 0 ? s / p : kNaN;
    const std::string det = e.value("determined", std::string());
    const bool undetermined = det == "not determined";
    std::string cls = ratio < 0.5 ? "estimated" : undetermined ? "undetermined" : "";
    std::string tol = "";
    if (verdict.contains(name)) {
      if (verdict[name].is_string()) {
        tol = "not tested";
      } else {
        const bool ok = verdict[name].get<bool>();
        cls += ok ? " pass" : " fail";
        tol = ok ? "pass" : "FAIL";
      }
    }
    // a parameter the run did not determine has no estimate to show: its
    // value is the prior's (kept in the JSON)
    const std::string why = escape(e.value("why", std::string()));
    o += "<tr class=\"" + cls + "\"><td>" + escape(name) + "</td><td>" +
         (undetermined ? "<span title=\"" + why + "\">not determined</span>"
                       : number(e["value"].get<double>() * k)) +
         "</td><td>" + (undetermined ? std::string("-") : number(s * k)) + "</td><td>" +
         number(p * k) + "</td><td>" + number(ratio, "%.3f") + (det == "partly" ? " partly" : "") +
         "</td><td>" + escape(std::string(unit)) + "</td><td>" + tol + "</td></tr>";
  }
  o += "</tbody></table>";
  if (r.contains("combinations") && !r["combinations"].empty()) {
    o += "<h2>Combinations the run determined</h2><table class=\"combos\"><thead><tr>"
         "<th>combination</th><th>value</th><th>sigma</th><th>prior "
         "sigma</th><th>unit</th></tr></thead><tbody>";
    for (const auto& c : r["combinations"]) {
      const std::string lead = c.value("lead", std::string());
      const auto [unit, k] = display_unit(lead);
      const std::string terms =
          escape(combination_terms(c, r)) +
          (c.contains("name") ? " (" + escape(c["name"].get<std::string>()) + ")" : "");
      o += "<tr><td class=\"combo\">" + terms + "</td><td>" + number(c["value"].get<double>() * k) +
           "</td><td>" + number(c["sigma"].get<double>() * k) + "</td><td>" +
           number(c["prior_sigma"].get<double>() * k) + "</td><td>" + escape(std::string(unit)) +
           "</td></tr>";
    }
    o += "</tbody></table>";
  }
  if (r.value("status", std::string()) == "done" && r.contains("estimates"))
    o += "<h2>Applying it</h2><p class=\"apply\">" + escape(kHowToApply) + "</p>";
  return o;
}

std::string summary(const json& r) {
  const std::string status = r.value("status", std::string("?"));
  const bool pass = r.contains("verdict") && r["verdict"].value("pass", false);
  std::string o = "<h1>turncal report " + escape(r.value("run_id", std::string("?"))) + "</h1>";
  o += "<p class=\"verdict " + std::string(pass ? "pass" : "fail") + "\">" +
       (pass ? "PASS" : "FAIL") + " &mdash; " + escape(status) +
       (r.contains("reason") ? ": " + escape(r["reason"].get<std::string>()) : "") + "</p>";
  o += "<dl>";
  auto item = [&](const std::string& k, const std::string& v) {
    o += "<dt>" + escape(k) + "</dt><dd>" + escape(v) + "</dd>";
  };
  if (r.contains("profile"))
    item("profile", r["profile"].value("name", std::string()) + " (" +
                        fmt("%.0f s", r["profile"].value("duration_s", 0.0)) + ")");
  item("mode", r.value("mode", std::string()));
  if (r.contains("log")) item("log", log_text(r["log"]));
  if (r.contains("site"))
    item("site", fmt("latitude %.4f deg", r["site"].value("latitude_rad", 0.0) * kRadToDeg) +
                     fmt(", height %.0f m", r["site"].value("height_m", 0.0)));
  for (const auto& t : r.value("turns_achieved", json::array()))
    item("turn", fmt("%.4f deg", t["angle_rad"].get<double>() * kRadToDeg) +
                     fmt(" at peak %.3f deg/s", t["peak_rate_rps"].get<double>() * kRadToDeg) +
                     fmt(", %.2f s", t["start_s"].get<double>()) +
                     fmt(" to %.2f s after t0", t["end_s"].get<double>()));
  if (r.contains("innovations")) {
    const json& i = r["innovations"];
    item("innovations", fmt("NIS mean %.3f", i.value("nis_mean", 0.0)) +
                            " (95%: " + fmt("%.3f", i["nis_95_interval"][0].get<double>()) +
                            " to " + fmt("%.3f", i["nis_95_interval"][1].get<double>()) + "); " +
                            whiteness_text(i));
  }
  if (r.contains("replay") && r["replay"].is_object() && r["replay"].contains("damage") &&
      r["replay"]["damage"].is_object())
    item("log damage", "line " + std::to_string(r["replay"]["damage"].value("line", 0)) + ": " +
                           r["replay"]["damage"].value("what", std::string()));
  o += "</dl>";
  return o;
}

constexpr const char* kStyle = R"(
body{font:14px/1.4 system-ui,sans-serif;margin:24px auto;max-width:800px;color:#222}
h1{font-size:22px}h2{font-size:17px;margin-top:28px}
dl{display:grid;grid-template-columns:max-content auto;gap:2px 14px}dt{color:#666}dd{margin:0}
.verdict{font-weight:600;padding:6px 10px;border-radius:4px}
.verdict.pass{background:#e3f4e3;color:#185c18}.verdict.fail{background:#fbe3e3;color:#8a1414}
table{border-collapse:collapse;width:100%;font-variant-numeric:tabular-nums}
th,td{padding:2px 8px;text-align:right;border-bottom:1px solid #ddd}
th:first-child,td:first-child{text-align:left}td.combo{font-size:12px}
tr.estimated td:first-child{font-weight:600}tr.pass{background:#eef8ee}tr.fail{background:#fbe3e3}
figure.plot{margin:12px 0}svg{width:100%;height:auto;font-size:11px}
.title{font-size:13px;font-weight:600}.frame{fill:none;stroke:#444}
.grid{stroke:#e4e4e4}.tick{fill:#555}.label{fill:#333}.legend{font-weight:600}
.line{fill:none;stroke-width:1.2}.turn{fill:#ffe9b0;opacity:.6}.readout{fill:#000}
)";

// Reads the value under the pointer; counts the plots it set up.
constexpr const char* kScript = R"(
(function(){
  var plots=document.querySelectorAll('figure.plot svg[data-x0]');
  plots.forEach(function(s){
    var r=s.querySelector('.readout'),f=s.querySelector('.frame');
    s.addEventListener('mousemove',function(e){
      var p=s.createSVGPoint();p.x=e.clientX;p.y=e.clientY;
      var q=p.matrixTransform(s.getScreenCTM().inverse());
      var x=+f.getAttribute('x'),y=+f.getAttribute('y'),w=+f.getAttribute('width'),h=+f.getAttribute('height');
      if(q.x<x||q.x>x+w||q.y<y||q.y>y+h){r.textContent='';return;}
      var d=s.dataset,tx=+d.x0+(q.x-x)/w*(d.x1-d.x0),ty=+d.y0+(1-(q.y-y)/h)*(d.y1-d.y0);
      if(d.log==='1')ty=Math.pow(10,ty);
      r.textContent='x '+tx.toPrecision(5)+'  y '+ty.toPrecision(4);
    });
  });
  document.body.dataset.plots=String(plots.length);
})();
)";

}  // namespace

std::string report_html(const json& r, const BuiltInput* input,
                        const est::EstimationResult* result) {
  std::string o =
      "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
      "<meta name=\"viewport\" content=\"width=device-width,initial-scale=1\">"
      "<title>turncal report " +
      escape(r.value("run_id", std::string())) + "</title><style>" + kStyle +
      "</style></head><body>\n";
  o += summary(r);
  o += parameter_table(r);
  std::vector<Span> turns;
  for (const auto& t : r.value("turns_achieved", json::array()))
    turns.push_back({t["start_s"].get<double>(), t["end_s"].get<double>()});
  if (input != nullptr && result != nullptr) {
    o += "<h2>Accuracy against time</h2>";
    for (const SigmaPlotGroup& g : sigma_plot_groups()) {
      const auto [unit, k] =
          display_unit(est::kParamNames[static_cast<std::size_t>(g.params.front())]);
      Plot p(g.title, "time from t0, s", "sigma, " + std::string(unit), true);
      for (std::size_t n = 0; n < g.params.size(); ++n) {
        const int j = g.params[n];
        Series s{std::string(est::kParamNames[static_cast<std::size_t>(j)]),
                 kColors[n % kColors.size()],
                 result->epoch_t,
                 {}};
        s.y.reserve(result->sigma_history.size());
        for (const est::StateVec& sv : result->sigma_history)
          s.y.push_back(sv(est::sx::kNu0 + j) * k);
        if (g.params.size() > 6) s.name = n == 0 ? "Theta (9)" : "";
        p.add(std::move(s));
      }
      p.mark(turns);
      o += p.svg();
    }
    o += "<h2>INS velocity and filter residuals</h2>";
    {
      const auto& v = input->input.velocity;
      // thinned on the axis the plot will have (the samples' time span)
      const Axis axis = v.empty() ? Plot::axis(0, 1) : Plot::axis(v.front().t_s, v.back().t_s);
      Thinned e(axis), n(axis);
      for (const est::VelocityObs& s : v) {
        e.add(s.t_s, s.ve * 1e3);
        n.add(s.t_s, s.vn * 1e3);
      }
      Plot p("INS output velocity (on a still base: its error)", "time from t0, s", "mm/s");
      auto [ex, ey] = e.take();
      auto [nx, ny] = n.take();
      p.add({"east", kColors[0], std::move(ex), std::move(ey)});
      p.add({"north", kColors[1], std::move(nx), std::move(ny)});
      p.mark(turns);
      o += p.svg();
    }
    std::vector<double> normalized;
    {
      Series e{"east", kColors[0], {}, {}}, n{"north", kColors[1], {}, {}};
      for (const est::Innovation& in : result->innovations) {
        e.x.push_back(in.t_s);
        e.y.push_back(in.value(0) * 1e3);
        n.x.push_back(in.t_s);
        n.y.push_back(in.value(1) * 1e3);
        const Eigen::LLT<Eigen::Matrix2d> llt(in.cov);
        if (llt.info() != Eigen::Success) continue;
        const Eigen::Vector2d z = llt.matrixL().solve(Eigen::Vector2d(in.value(0), in.value(1)));
        normalized.push_back(z(0));
        normalized.push_back(z(1));
      }
      Plot p("Filter residuals (innovations)", "time from t0, s", "mm/s");
      p.add(std::move(e));
      p.add(std::move(n));
      p.mark(turns);
      o += p.svg();
    }
    o += "<h2>Table</h2>";
    {
      const double offset =
          r.contains("settings") ? r["settings"].value("heading_offset_rad", 0.0) : 0.0;
      const auto& enc = input->input.timeline.encoder;
      Series a{"", kColors[0], {}, {}}, w{"", kColors[2], {}, {}};
      for (std::size_t i = 0; i < enc.size(); ++i) {
        a.x.push_back(enc[i].t_s);
        a.y.push_back((enc[i].psi_rad + offset) * kRadToDeg);
        if (i > 0 && enc[i].t_s - enc[i - 1].t_s > 1e-4) {
          w.x.push_back(0.5 * (enc[i].t_s + enc[i - 1].t_s));
          w.y.push_back((enc[i].psi_rad - enc[i - 1].psi_rad) / (enc[i].t_s - enc[i - 1].t_s) *
                        kRadToDeg);
        }
      }
      Plot pa("Table angle", "time from t0, s", "deg");
      pa.add(std::move(a));
      pa.mark(turns);
      o += pa.svg();
      Plot pr("Table rate", "time from t0, s", "deg/s");
      pr.add(std::move(w));
      pr.mark(turns);
      o += pr.svg();
    }
    o += "<h2>Normalized innovations</h2>";
    {
      // 0.25-wide bins over [-5, 5]; the N(0, 1) density scaled to the count
      constexpr double kBin = 0.25;
      constexpr int kBins = 40;
      Series h{"observed", "#7f9fc7", {}, std::vector<double>(kBins, 0.0)};
      for (int b = 0; b < kBins; ++b) h.x.push_back(-5 + (b + 0.5) * kBin);
      for (const double z : normalized) {
        const int b = static_cast<int>(std::floor((z + 5) / kBin));
        if (b >= 0 && b < kBins) h.y[static_cast<std::size_t>(b)] += 1;
      }
      Series g{"N(0,1)", kColors[1], {}, {}};
      const double n = static_cast<double>(normalized.size());
      for (int i = 0; i <= 200; ++i) {
        const double z = -5 + i * 0.05;
        g.x.push_back(z);
        g.y.push_back(n * kBin * std::exp(-0.5 * z * z) / std::sqrt(2 * std::numbers::pi));
      }
      Plot hist("Histogram of the normalized innovations (both axes)", "innovation / its sigma",
                "count");
      hist.add(std::move(h));
      hist.add(std::move(g));
      hist.bars();
      o += hist.svg();
    }
  }
  o += "<script>" + std::string(kScript) + "</script>\n</body></html>\n";
  return o;
}

}  // namespace turncal::run
