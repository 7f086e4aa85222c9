#include "state_dir.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>
#include <vector>

#include "turncal/can/candump.hpp"
#include "turncal/run/report.hpp"

namespace turncal::daemon {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

ssize_t sys_write(int fd, const void* data, std::size_t size) {
  return ::write(fd, data, size);
}
int sys_fsync(int fd) {
  return ::fsync(fd);
}
int sys_close(int fd) {
  return ::close(fd);
}
int sys_ftruncate(int fd, off_t length) {
  return ::ftruncate(fd, length);
}
int sys_fstat(int fd, struct stat* st) {
  return ::fstat(fd, st);
}

constexpr const char* kReportSuffix = ".report.json";

}  // namespace

const FileIo& posix_io() {
  static const FileIo io{sys_write, sys_fsync, sys_close, sys_ftruncate, sys_fstat};
  return io;
}

Status StateDir::create() const {
  std::error_code ec;
  fs::create_directories(dir_, ec);
  if (ec)
    return make_error("cannot create the state directory " + dir_.string() + ": " + ec.message());
  return Status{Ok{}};
}

DirLock::~DirLock() {
  if (fd_ >= 0) (void)::close(fd_);  // the lock goes with the descriptor
}

Result<DirLock> take_lock(const fs::path& file, const std::string& held_elsewhere) {
  // never through a link another user planted, and only a regular file;
  // read only, which is all flock needs: a lock file a start as root left
  // (0644, root's) does not stop a later daemon of another user
  const int fd =
      ::open(file.c_str(), O_RDONLY | O_CREAT | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC, 0644);
  if (fd < 0) return make_error("cannot open " + file.string() + ": " + std::strerror(errno));
  DirLock held(fd);
  struct stat st {};
  if (::fstat(fd, &st) != 0)
    return make_error("cannot stat " + file.string() + ": " + std::strerror(errno));
  if (!S_ISREG(st.st_mode)) return make_error(file.string() + ": not a regular file, no lock");
  int rc = 0;
  while ((rc = ::flock(fd, LOCK_EX | LOCK_NB)) != 0 && errno == EINTR) {
  }
  if (rc != 0) {
    if (errno == EWOULDBLOCK) return make_error(held_elsewhere);
    return make_error("cannot lock " + file.string() + ": " + std::strerror(errno));
  }
  return held;
}

Result<DirLock> StateDir::lock() const {
  const fs::path file = dir_ / ".lock";
  return take_lock(file, "the state directory " + dir_.string() +
                             " is held by another process (another turncald?): its lock " +
                             file.string() + " is taken; one daemon per state directory");
}

Status StateDir::write_atomic(const std::string& name, const std::string& data) const {
  const fs::path path = dir_ / name;
  const fs::path tmp = path.string() + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return make_error("cannot create " + tmp.string() + ": " + std::strerror(errno));
  auto fail = [&](const char* what, int err) {
    (void)io_->close(fd);
    ::unlink(tmp.c_str());
    return make_error(std::string("cannot ") + what + " " + tmp.string() + ": " +
                      std::strerror(err));
  };
  std::size_t off = 0;
  while (off < data.size()) {
    const ssize_t n = io_->write(fd, data.data() + off, data.size() - off);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return fail("write", errno);
    if (n == 0) return fail("write", EIO);
    off += static_cast<std::size_t>(n);
  }
  if (io_->fsync(fd) != 0) return fail("sync", errno);
  if (io_->close(fd) != 0) {
    const int err = errno;
    ::unlink(tmp.c_str());
    return make_error("cannot close " + tmp.string() + ": " + std::strerror(err));
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    const int err = errno;
    ::unlink(tmp.c_str());
    return make_error("cannot put " + path.string() + " in place: " + std::strerror(err));
  }
  const int dfd = ::open(dir_.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd < 0) return make_error("cannot open " + dir_.string() + ": " + std::strerror(errno));
  const bool synced = io_->fsync(dfd) == 0;
  const int err = errno;
  (void)::close(dfd);
  if (!synced) return make_error("cannot sync " + dir_.string() + ": " + std::strerror(err));
  return Status{Ok{}};
}

Result<json> StateDir::write_report_files(const std::string& run_id, const json& report,
                                          const std::string& text, const std::string& html) const {
  TURNCAL_TRY(write_atomic(run_id + ".report.txt", text));
  TURNCAL_TRY(write_atomic(run_id + ".report.html", html));
  const std::string data = report.dump(2, ' ', false, json::error_handler_t::replace) + "\n";
  TURNCAL_TRY(write_atomic(run_id + kReportSuffix, data));
  return json::parse(data, nullptr, false);  // what a reader will find
}

Status StateDir::write_report(const std::string& run_id, const json& report,
                              const std::string& text, const std::string& html) {
  TURNCAL_ASSIGN(written, write_report_files(run_id, report, text, html));
  index_report(run_id, written);
  return Status{Ok{}};
}

namespace {
constexpr const char* kReserveSuffix = ".reserve";
}  // namespace

/// The file's blocks for `bytes`, taken from the file system now: by
/// fallocate where the file system has it, else by writing zeros in large
/// pieces (glibc's posix_fallocate writes a byte a block there: thousands
/// of calls, long enough to hold up the loop's heartbeat). 0 or an errno.
int StateDir::allocate(int fd, std::uint64_t bytes) const {
  if (::fallocate(fd, 0, 0, static_cast<off_t>(bytes)) == 0) return 0;
  if (errno != EOPNOTSUPP) return errno;
  static const std::vector<char> zeros(std::size_t{1} << 20);
  for (std::uint64_t done = 0; done < bytes;) {
    const std::size_t n =
        static_cast<std::size_t>(std::min<std::uint64_t>(zeros.size(), bytes - done));
    const ssize_t w = io_->write(fd, zeros.data(), n);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) return w == 0 ? ENOSPC : errno;
    done += static_cast<std::uint64_t>(w);
  }
  return 0;
}

Status StateDir::reserve(const std::string& run_id, std::uint64_t bytes) const {
  if (bytes == 0) return Status{Ok{}};
  const fs::path p = dir_ / ("." + run_id + kReserveSuffix);
  const int fd = ::open(p.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
  if (fd < 0) return make_error("cannot create " + p.string() + ": " + std::strerror(errno));
  const int err = allocate(fd, bytes);
  const bool closed = io_->close(fd) == 0;
  if (err != 0 || !closed) {
    ::unlink(p.c_str());
    return make_error(
        "the state directory cannot hold a run's report: " + std::to_string(bytes >> 10) +
        " KiB could not be reserved: " + std::strerror(err != 0 ? err : EIO));
  }
  return Status{Ok{}};
}

void StateDir::release(const std::string& run_id) const {
  ::unlink((dir_ / ("." + run_id + kReserveSuffix)).c_str());
}

void StateDir::release_stale() const {
  std::error_code ec;
  for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string n = it->path().filename().string();
    if (n.starts_with(".") && n.ends_with(kReserveSuffix)) ::unlink(it->path().c_str());
  }
}

/// A kept report, parsed and checked; the error is why it cannot be read.
Result<json> StateDir::load(const std::string& run_id) const {
  const fs::path p = dir_ / (run_id + kReportSuffix);
  std::ifstream in(p, std::ios::binary);
  if (!in) return make_error("no such file");
  std::stringstream ss;
  ss << in.rdbuf();
  if (in.bad()) return make_error("read error");
  json r = json::parse(ss.str(), nullptr, false);
  if (r.is_discarded()) return make_error("not JSON");
  if (const std::string why = run::check_report(r); !why.empty()) return make_error(why);
  return r;
}

Result<json> StateDir::read_report(const std::string& run_id) const {
  if (!valid_name(run_id)) return make_error("report: expected a run_id");
  std::error_code ec;
  if (!fs::exists(dir_ / (run_id + kReportSuffix), ec)) return make_error("no report " + run_id);
  auto r = load(run_id);
  if (!r) return make_error("report " + run_id + " unreadable: " + r.error().message);
  return r;
}

void StateDir::index_report(const std::string& run_id, const json& report) {
  IndexEntry e;
  if (const std::string why = run::check_report(report); !why.empty())
    e.unreadable = why;
  else
    e.summary = report_summary(report);
  index_[run_id] = std::move(e);
}

void StateDir::load_index() {
  std::error_code ec;
  // increment(ec), not ++: a failing disk must not throw out of start-up
  for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string n = it->path().filename().string();
    if (!n.ends_with(kReportSuffix)) continue;
    const std::string id = n.substr(0, n.size() - std::strlen(kReportSuffix));
    if (!valid_name(id) || index_.contains(id)) continue;  // indexed when written
    // checked once, here: the summary of a readable one, else why not
    auto r = load(id);
    index_[id] = r ? IndexEntry{report_summary(*r), ""} : IndexEntry{json(), r.error().message};
  }
}

bool StateDir::has_log(const std::string& run_id) const {
  std::error_code ec;
  return fs::exists(dir_ / (run_id + ".log"), ec);
}

LogsWithoutReport StateDir::logs_without_report() const {
  LogsWithoutReport out;
  std::error_code ec;
  for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (!name.ends_with(".log")) continue;
    // a run's log is a regular file; a link or anything else is no run's
    // (its digest would read what it points at, or never end)
    std::error_code kind;
    const fs::file_status st = it->symlink_status(kind);
    if (kind) {
      out.skipped.push_back(name + ": cannot tell what it is: " + kind.message());
      continue;
    }
    if (st.type() != fs::file_type::regular) {
      out.skipped.push_back(
          name + ": " + (st.type() == fs::file_type::symlink ? "a link" : "not a regular file") +
          ", no run's log; left as it is");
      continue;
    }
    const std::string id = name.substr(0, name.size() - 4);
    std::error_code gone;
    if (!fs::exists(dir_ / (id + kReportSuffix), gone)) out.runs.push_back(id);
  }
  if (ec)
    out.skipped.push_back("the state directory " + dir_.string() +
                          " could not be listed (all of it, or to its end): " + ec.message());
  return out;
}

std::string printable_bytes(std::string_view bytes) {
  std::string out;
  out.reserve(bytes.size());
  for (const char ch : bytes) {
    const auto u = static_cast<unsigned char>(ch);
    if (u == '\\') {
      out += "\\\\";
    } else if (u >= 0x20 && u < 0x7f && u != '"') {
      out += ch;
    } else {
      static constexpr char kHex[] = "0123456789abcdef";
      out += "\\x";
      out += kHex[u >> 4];
      out += kHex[u & 0xf];
    }
  }
  return out;
}

TailCut StateDir::cut_torn_tail(const std::string& run_id) const {
  const fs::path file = dir_ / (run_id + ".log");
  TailCut out;
  const auto failed = [&](const std::string& what, int err) {
    out.error =
        file.string() + ": " + what + (err != 0 ? std::string(": ") + std::strerror(err) : "");
    return out;
  };
  // read only, and only a regular file (never a link's target), until a cut is due
  // (never blocking: a FIFO in its place would hold the start up)
  const int rfd = ::open(file.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
  if (rfd < 0) return failed("cannot open", errno);
  struct stat st {};
  const bool stat_ok = io_->fstat(rfd, &st) == 0;
  const int stat_err = errno;
  if (!stat_ok || !S_ISREG(st.st_mode)) {
    (void)::close(rfd);
    return stat_ok ? failed("not a regular file; left as it is", 0)
                   : failed("cannot stat", stat_err);
  }
  out.regular = true;
  const auto size = static_cast<std::uint64_t>(st.st_size);
  // a kill's part of a line is shorter than kMaxLogLine, the bound on a
  // whole line with its newline (the longest format_log_line writes is
  // shorter still): the last kMaxLogLine bytes hold its start
  const std::uint64_t span = std::min<std::uint64_t>(size, can::kMaxLogLine);
  std::string tail(span, '\0');
  std::uint64_t got = 0;
  int read_err = 0;
  while (got < span) {
    const ssize_t n =
        ::pread(rfd, tail.data() + got, span - got, static_cast<off_t>(size - span + got));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      read_err = n < 0 ? errno : EIO;
      break;
    }
    got += static_cast<std::uint64_t>(n);
  }
  (void)::close(rfd);  // read only: nothing of it to lose
  if (read_err != 0) return failed("cannot read its end", read_err);
  const std::size_t nl = tail.rfind('\n');
  if (nl == tail.size() - 1 || span == 0) return out;  // ends with a whole line
  if (nl == std::string::npos && size >= can::kMaxLogLine)
    return failed("its last " + std::to_string(span) +
                      " bytes hold no line's end: longer than any line, not a line cut short; "
                      "left as it is",
                  0);
  const std::string part = nl == std::string::npos ? tail : tail.substr(nl + 1);
  const std::uint64_t keep = size - part.size();
  const int fd = ::open(file.c_str(), O_WRONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) return failed("cannot open to cut its last, partial line", errno);
  struct stat again {};
  if (io_->fstat(fd, &again) != 0) {
    const int err = errno;
    (void)io_->close(fd);
    return failed("cannot stat it to cut its last, partial line", err);
  }
  if (again.st_ino != st.st_ino || again.st_dev != st.st_dev || again.st_size != st.st_size) {
    (void)io_->close(fd);
    return failed("changed while it was read; left as it is", 0);
  }
  if (io_->ftruncate(fd, static_cast<off_t>(keep)) != 0) {
    const int err = errno;
    (void)io_->close(fd);
    return failed("cannot cut its last, partial line", err);
  }
  out.bytes = part;  // cut: whatever fails next, these bytes are gone from the file
  if (io_->fsync(fd) != 0) {
    const int err = errno;
    (void)io_->close(fd);
    return failed("its partial line was cut, but the sync failed", err);
  }
  if (io_->close(fd) != 0) return failed("its partial line was cut, but the close failed", errno);
  return out;
}

std::vector<PrunedLog> StateDir::prune_logs(const Retention& r, double now_unix_s,
                                            const std::string& keep) const {
  struct Log {
    std::string id;
    std::uint64_t bytes;
    double mtime_s;
    bool removable;
  };
  std::vector<Log> logs;
  std::error_code ec;
  for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (!name.ends_with(".log")) continue;
    struct stat st {};
    if (::stat(it->path().c_str(), &st) != 0 || !S_ISREG(st.st_mode)) continue;
    const std::string id = name.substr(0, name.size() - 4);
    // removable only with a report that reads and holds the run: not an
    // unreadable one, nor the note of an interrupted run (its log is all)
    const auto at = index_.find(id);
    const bool reported = at != index_.end() && at->second.unreadable.empty() &&
                          at->second.summary.is_object() && at->second.summary.contains("status") &&
                          at->second.summary["status"] != "interrupted";
    logs.push_back(
        {id, static_cast<std::uint64_t>(st.st_size),
         static_cast<double>(st.st_mtim.tv_sec) + static_cast<double>(st.st_mtim.tv_nsec) * 1e-9,
         reported && id != keep});
  }
  // run ids are UTC times: by name is oldest first
  std::sort(logs.begin(), logs.end(), [](const Log& a, const Log& b) { return a.id < b.id; });
  std::uint64_t total = 0;
  for (const Log& l : logs) total += l.bytes;
  std::vector<PrunedLog> out;
  auto remove = [&](Log& l, std::string why) {
    PrunedLog p{l.id, l.bytes, std::move(why), ""};
    if (::unlink((dir_ / (l.id + ".log")).c_str()) != 0) {
      p.error = std::strerror(errno);
    } else {
      total -= l.bytes;
    }
    l.removable = false;
    out.push_back(std::move(p));
  };
  if (r.keep_days > 0) {
    char why[64];
    std::snprintf(why, sizeof why, "older than %g days", r.keep_days);
    for (Log& l : logs)
      if (l.removable && now_unix_s - l.mtime_s > r.keep_days * 86400) remove(l, why);
  }
  if (r.max_log_bytes > 0) {
    char why[64];
    std::snprintf(why, sizeof why, "the logs took over %.1f MiB",
                  static_cast<double>(r.max_log_bytes) / (1 << 20));
    for (Log& l : logs) {
      if (total <= r.max_log_bytes) break;
      if (l.removable) remove(l, why);
    }
  }
  return out;
}

Result<std::uint64_t> StateDir::free_bytes() const {
  struct statvfs v {};
  if (::statvfs(dir_.c_str(), &v) != 0)
    return make_error("cannot read the free space of " + dir_.string() + ": " +
                      std::strerror(errno));
  return static_cast<std::uint64_t>(v.f_bavail) * v.f_frsize;
}

void BusRate::add(std::uint64_t t_us, std::uint64_t frames) {
  if (!points_.empty() && (frames < points_.back().second || t_us < points_.back().first))
    points_.clear();
  points_.emplace_back(t_us, frames);
  constexpr std::uint64_t kWindowUs = 10'000'000;
  while (points_.size() > 2 && t_us - points_[1].first >= kWindowUs) points_.pop_front();
}

double BusRate::per_s() const {
  if (points_.size() < 2) return NAN;
  const double dt = static_cast<double>(points_.back().first - points_.front().first) * 1e-6;
  if (dt < 1.0) return NAN;
  return static_cast<double>(points_.back().second - points_.front().second) / dt;
}

std::uint64_t log_bytes_bound(double frames, std::size_t interface_chars) {
  if (!(frames > 0)) return 0;
  if (!(frames < 1e15)) return std::numeric_limits<std::uint64_t>::max();
  can::LogRecord r;
  r.time_ns = 9'999'999'999'999'999;  // ten digits of seconds, as until 2286
  r.interface.assign(interface_chars, 'x');
  r.frame.id = 0x1FFFFFFF;
  r.frame.extended = true;
  r.frame.len = 8;
  const std::size_t line = can::format_log_line(r).size();
  return static_cast<std::uint64_t>(std::ceil(frames)) * line;
}

}  // namespace turncal::daemon
