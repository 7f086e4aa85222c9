// Child processes, temporary folders and log files for the hil tier.
#pragma once

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "turncal/can/candump.hpp"

namespace hil {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

/// A child process (fork + exec), its stdout optionally into a file.
class Child {
 public:
  /// Runs argv in cwd; its stdout into `out` and its stderr into `err`
  /// where given.
  Child(std::vector<std::string> argv, const fs::path& cwd, const fs::path& out = {},
        const fs::path& err = {}) {
    pid_ = ::fork();
    if (pid_ == 0) {
      if (::chdir(cwd.c_str()) != 0) ::_exit(126);
      for (const auto& [path, to] : {std::pair{&out, 1}, std::pair{&err, 2}}) {
        if (path->empty()) continue;
        const int fd = ::open(path->c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
        if (fd < 0 || ::dup2(fd, to) < 0) ::_exit(126);
      }
      std::vector<char*> args;
      for (auto& a : argv) args.push_back(a.data());
      args.push_back(nullptr);
      ::execvp(args[0], args.data());
      ::_exit(127);
    }
  }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;
  Child(Child&& o) noexcept : pid_(o.pid_) { o.pid_ = -1; }
  Child& operator=(Child&&) = delete;
  [[nodiscard]] pid_t pid() const { return pid_; }
  /// Asks it to stop (SIGTERM).
  void terminate() {
    if (pid_ > 0) ::kill(pid_, SIGTERM);
  }
  ~Child() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  /// What the kernel says the child is doing ("S do_select", "R 0"...):
  /// what a child that did not end in time shows before it is killed.
  [[nodiscard]] std::string proc_state() const {
    if (pid_ <= 0) return "ended";
    const std::string base = "/proc/" + std::to_string(pid_) + "/";
    std::string stat = read_small(base + "stat");
    const auto close = stat.rfind(')');
    const std::string state = close != std::string::npos && close + 2 < stat.size()
                                  ? stat.substr(close + 2, 1)
                                  : std::string("?");
    return state + " " + read_small(base + "wchan");
  }
  /// Exit status, 128 + the signal's number when a signal ended it (as a
  /// shell says), or -1 when it did not end within `timeout` (then killed).
  int wait(std::chrono::milliseconds timeout) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    int status = 0;
    while (std::chrono::steady_clock::now() < end) {
      const pid_t r = ::waitpid(pid_, &status, WNOHANG);
      if (r == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      }
      std::this_thread::sleep_for(10ms);
    }
    return -1;
  }

 private:
  static std::string read_small(const std::string& path) {
    const int fd = ::open(path.c_str(), O_RDONLY);
    if (fd < 0) return "?";
    char buf[512];
    const ssize_t n = ::read(fd, buf, sizeof buf);
    ::close(fd);
    return n > 0 ? std::string(buf, static_cast<std::size_t>(n)) : std::string("?");
  }
  pid_t pid_ = -1;
};

/// A folder of its own under $TMPDIR (in the user-mode Linux guest, a
/// tmpfs of the guest's: scripts/vcan-run says why), else /tmp.
struct TempDir {
  fs::path path;
  TempDir() {
    const char* base = std::getenv("TMPDIR");
    std::string tmpl =
        std::string(base != nullptr && *base != '\0' ? base : "/tmp") + "/turncal-hil.XXXXXX";
    if (::mkdtemp(tmpl.data()) == nullptr)
      throw std::runtime_error("mkdtemp " + tmpl + ": " + std::strerror(errno));
    path = tmpl;
  }
  ~TempDir() { fs::remove_all(path); }
};

/// Files a failed test case shows the end of (a daemon's log kept in a
/// file): registered as the case makes them, forgotten when the next case
/// starts. The hil tier fails on timing as well as on logic, and what the
/// daemon said is the evidence; its temporary directory is gone by the time
/// anyone reads a CI log.
inline std::vector<fs::path>& explain_files() {
  static std::vector<fs::path> files;
  return files;
}

inline std::vector<turncal::can::LogRecord> read_log(const fs::path& p) {
  std::vector<turncal::can::LogRecord> out;
  auto rd = turncal::can::LogReader::open(p.string());
  if (!rd.ok()) throw std::runtime_error(rd.error().describe());
  for (;;) {
    auto r = rd->next();
    if (!r.ok()) throw std::runtime_error(r.error().describe());
    if (!r->has_value()) break;
    out.push_back(std::move(**r));
  }
  return out;
}

}  // namespace hil
