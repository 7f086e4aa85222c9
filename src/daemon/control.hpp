// The control protocol of turncald, pure: one request line and a view of
// the daemon in, the reply and the action the loop must take out. Every
// field a request carries is type-checked here, so a request of any shape
// gets an error reply and never an exception out of the event loop; the
// loop only wires sockets to it (clients.cpp), and the fuzz target drives it
// with any bytes.
//
// Requests are JSON objects, one a line: {"cmd": "status" | "watch" |
// "start" | "abort" | "reports" | "history" | "report", ...}. A start names
// its plan by its text ("plan_text", read by the operator's turncalctl) or
// by a bare name from the configured profiles directory ("profile"): the
// daemon never opens a path a client gives.
#pragma once

#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <variant>

#include "turncal/result.hpp"

namespace turncal::daemon {

struct StatusRequest {};
struct WatchRequest {};
struct StartRequest {
  std::string plan_text;  ///< the plan's TOML, as the operator read it; empty: none sent
  std::string plan_name;  ///< a bare name in the profiles directory, or the text's file name
  bool observe = false;
  std::optional<double> heading_offset_deg;
  std::optional<std::string> unit;
};
struct AbortRequest {
  std::string reason;
};
struct ReportsRequest {};
struct HistoryRequest {
  std::string unit;
};
struct ReportRequest {
  std::string run_id;
};
using Request = std::variant<StatusRequest, WatchRequest, StartRequest, AbortRequest,
                             ReportsRequest, HistoryRequest, ReportRequest>;

/// The largest plan text a start may carry, bytes.
inline constexpr std::size_t kMaxPlanText = 48 * 1024;

/// One request line into a request; the error is the reply's text.
Result<Request> parse_request(std::string_view line);

/// A unit identity safe in a file listing and a log line: 1 to 64 letters,
/// digits, '-', '_' or '.'.
bool valid_unit(std::string_view unit);
/// A run id or plan name safe to put in a file name: like a unit, and not
/// "." or "..".
bool valid_name(std::string_view name);

/// A report the daemon keeps: its summary, or why it cannot be read.
struct IndexEntry {
  nlohmann::json summary;  ///< run_id, status, unit, start time, profile name, pass, estimates
  std::string unreadable;  ///< non-empty: the report is not readable, and why
};
using Index = std::map<std::string, IndexEntry>;

/// What `reports` and `history` need of a report (it has passed check_report).
nlohmann::json report_summary(const nlohmann::json& report);

/// What a request may see of the daemon.
struct View {
  std::function<nlohmann::json()> status;  ///< the status reply
  bool running = false;                    ///< a run is in progress
  const Index* index = nullptr;
  /// A kept report by run id (checked), or why not.
  std::function<Result<nlohmann::json>(const std::string& run_id)> read_report;
};

/// What the loop does after a request: reply (unless the action replies),
/// start watching, start or abort a run.
struct Outcome {
  nlohmann::json reply;  ///< null: the action's result is the reply
  bool watch = false;
  std::optional<std::variant<StartRequest, AbortRequest>> action;
};

Outcome dispatch(std::string_view line, const View& view);

}  // namespace turncal::daemon
