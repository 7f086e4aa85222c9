// libFuzzer target: the daemon's control protocol (any bytes as a request
// line, against a daemon view with an index of reports) and the report
// reader (any bytes as a report file: check_report, then the text, the
// summary and the history that read it). Nothing may throw or crash.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "control.hpp"
#include "turncal/run/history.hpp"
#include "turncal/run/report.hpp"

using nlohmann::json;
using namespace turncal;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  daemon::Index index;
  // the same bytes as a report file the daemon finds in its state directory
  const json r = json::parse(text, nullptr, false);
  const std::string why = r.is_discarded() ? "not JSON" : run::check_report(r);
  if (!r.is_discarded()) {
    if (why.empty()) {
      (void)run::report_text(r);
      index["fuzz"] = daemon::IndexEntry{daemon::report_summary(r), ""};
    } else {
      index["fuzz"] = daemon::IndexEntry{json(), why};
    }
  }
  daemon::View v;
  v.status = [] { return json{{"ok", true}, {"phase", "idle"}}; };
  v.running = size % 2 == 0;
  v.index = &index;
  v.read_report = [&](const std::string&) -> Result<json> {
    if (why.empty()) return r;
    return make_error("unreadable");
  };
  const daemon::Outcome o = daemon::dispatch(text, v);
  if (o.reply.is_null() && !o.action) std::abort();  // every request is answered
  (void)o.reply.dump(-1, ' ', false, json::error_handler_t::replace);
  // a history of the unit the report names, whatever it holds
  std::vector<json> all;
  for (const auto& [id, e] : index)
    if (e.unreadable.empty()) all.push_back(e.summary);
  (void)run::history_text(run::history_json("SN-1", all));
  return 0;
}
