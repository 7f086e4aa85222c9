// turncald: the calibration experiment as a service (daemon.hpp).
//
//   turncald [--config FILE] [--state-dir DIR] [--socket PATH]
#include <systemd/sd-daemon.h>

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>
#include <utility>

#include "daemon.hpp"

using namespace turncal;
using namespace turncal::daemon;

namespace {

constexpr const char* kUsage =
    "usage: turncald [--config FILE] [--state-dir DIR] [--socket PATH]\n"
    "The turntable calibration service (turncald(8)); turncalctl(1) talks to it.\n";

int usage(const char* why) {
  std::fprintf(stderr, "turncald: %s\n%s", why, kUsage);
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  log_to_journal(std::getenv("JOURNAL_STREAM") != nullptr ||
                 std::getenv("INVOCATION_ID") != nullptr);
  Options opt;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      std::fputs(kUsage, stdout);
      return std::fflush(stdout) == 0 && !std::ferror(stdout) ? 0 : 1;
    }
    if (i + 1 >= argc) return usage(("missing value after " + a).c_str());
    if (a == "--config")
      opt.config = argv[++i];
    else if (a == "--state-dir")
      opt.state_dir = argv[++i];
    else if (a == "--socket")
      opt.socket = argv[++i];
    else
      return usage(("unknown option " + a).c_str());
  }
  Daemon d(std::move(opt));
  Status st = make_error("setup did not run");
  try {
    st = d.setup();
  } catch (const std::exception& e) {  // a file system that fails under a directory walk
    st = make_error(std::string("setup: ") + e.what());
  }
  if (!st) {
    say(LOG_ERR, "", "idle", st.error().describe());
    sd_notifyf(0, "STATUS=failed: %s", st.error().describe().c_str());
    return 1;
  }
  return d.run();
}
