// The daemon's state directory as one unit: run logs, reports, the index
// of reports, atomic writes, and the runs a killed daemon left behind.
// Every write, flush, sync and close result is checked; a report file is
// read only through check_report, so a damaged or foreign file is an
// "unreadable" entry with its reason, never an exception.
#pragma once

#include <sys/stat.h>
#include <sys/types.h>

#include <cstdint>
#include <deque>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "control.hpp"
#include "turncal/result.hpp"

namespace turncal::daemon {

/// The system calls a state directory writes with: the real ones, or a
/// unit test's that fail on demand (a full disk, an I/O error).
struct FileIo {
  ssize_t (*write)(int fd, const void* data, std::size_t size);
  int (*fsync)(int fd);
  int (*close)(int fd);
  int (*ftruncate)(int fd, off_t length);
  int (*fstat)(int fd, struct stat* st);
};
const FileIo& posix_io();

/// Which run logs may go, applied before a run starts (config [daemon]).
struct Retention {
  double keep_days = 0;             ///< logs older than this go; 0: any age stays
  std::uint64_t max_log_bytes = 0;  ///< the oldest go until all take this; 0: no limit
};

/// A log retention removed, or tried to.
struct PrunedLog {
  std::string run_id;
  std::uint64_t bytes = 0;
  std::string why;    ///< "older than N days", "logs over N MiB"
  std::string error;  ///< empty: removed
};

/// The frame rate the bus has had lately (frames received and our own
/// confirmed, per second of real time), from the counters sampled on the
/// daemon's timer: what a run's log will grow at.
class BusRate {
 public:
  /// A sample of the frame counter at a monotonic time, us; a counter that
  /// went back (a socket re-opened) starts the window again.
  void add(std::uint64_t t_us, std::uint64_t frames);
  /// Frames per second over the window (the last 10 s); NaN when it spans
  /// less than 1 s.
  [[nodiscard]] double per_s() const;

 private:
  std::deque<std::pair<std::uint64_t, std::uint64_t>> points_;
};

/// The state directory held by one daemon: an exclusive lock on its
/// .lock file, kept while this lives, so a second daemon started on the
/// same directory is refused before it touches a file (it would release a
/// live run's reservation and cut a live log's last line).
class DirLock {
 public:
  DirLock() = default;
  explicit DirLock(int fd) : fd_(fd) {}
  DirLock(const DirLock&) = delete;
  DirLock& operator=(const DirLock&) = delete;
  DirLock(DirLock&& o) noexcept : fd_(std::exchange(o.fd_, -1)) {}
  DirLock& operator=(DirLock&& o) noexcept {
    std::swap(fd_, o.fd_);
    return *this;
  }
  ~DirLock();

 private:
  int fd_ = -1;
};

/// Takes `file` (made if missing) for this process: an exclusive flock,
/// held until the DirLock goes (or the process ends, however it ends).
/// When another process holds it, the error is `held_elsewhere`.
[[nodiscard]] Result<DirLock> take_lock(const std::filesystem::path& file,
                                        const std::string& held_elsewhere);

/// Bytes a log of `frames` records takes at most, on interfaces whose names
/// are at most `interface_chars` long (classic frames: a CAN FD frame's line
/// is longer; the reference stand has none).
std::uint64_t log_bytes_bound(double frames, std::size_t interface_chars);

/// Bytes as printable text: printable ASCII as it is but for a backslash
/// (doubled) and a double quote (\x22, so the text can be quoted), any
/// other byte as \xNN (what a kill left of a line, for a report).
std::string printable_bytes(std::string_view bytes);

/// What cutting a killed run's torn log tail did.
struct TailCut {
  std::string bytes;  ///< the bytes cut off (the part of a line); empty: none
  std::string
      error;  ///< empty: done (or nothing to do); else why not, or what failed after the cut
  bool regular = false;  ///< the log was opened and is a regular file (a run's log may be read)
};

/// The logs a killed daemon left (no report beside them), and the `.log`
/// entries that are no run's log (a link, a directory, a FIFO), each as
/// "name: why", to be said rather than passed over.
struct LogsWithoutReport {
  std::vector<std::string> runs;
  std::vector<std::string> skipped;
};

class StateDir {
 public:
  explicit StateDir(std::filesystem::path dir, const FileIo& io = posix_io())
      : dir_(std::move(dir)), io_(&io) {}

  [[nodiscard]] const std::filesystem::path& path() const { return dir_; }
  /// Creates the directory if missing.
  Status create() const;
  /// Takes the directory for this process (see DirLock); an error naming
  /// the directory when another process holds it.
  [[nodiscard]] Result<DirLock> lock() const;
  /// Temp file, write, fsync, close, rename, fsync of the directory: the file
  /// is whole or absent, and every step's failure is the error.
  Status write_atomic(const std::string& name, const std::string& data) const;
  /// A run's report as its three files: the text and the HTML first, the
  /// JSON last, so the JSON (which the index and the next start read) is
  /// there only when all three are; indexed as the file reads back.
  Status write_report(const std::string& run_id, const nlohmann::json& report,
                      const std::string& text, const std::string& html);
  /// The three files alone, as write_report writes them, not indexed (off
  /// the loop, which indexes it); the report as a reader will find it.
  Result<nlohmann::json> write_report_files(const std::string& run_id, const nlohmann::json& report,
                                            const std::string& text, const std::string& html) const;
  /// Space for a run's report, taken when the run starts (a file of `bytes`,
  /// allocated), so a disk that fills during the run can still say why;
  /// released just before the report is written. An error when the disk
  /// cannot give it.
  Status reserve(const std::string& run_id, std::uint64_t bytes) const;
  void release(const std::string& run_id) const;
  /// Reservations a killed daemon left behind.
  void release_stale() const;
  /// A kept report, parsed and type-checked.
  Result<nlohmann::json> read_report(const std::string& run_id) const;
  /// Reads every report into the index (at start-up).
  void load_index();
  /// A report just written goes into the index.
  void index_report(const std::string& run_id, const nlohmann::json& report);
  [[nodiscard]] const Index& index() const { return index_; }
  [[nodiscard]] bool has_log(const std::string& run_id) const;
  /// The run ids of logs without a report: runs a killed daemon left; and
  /// what was passed over, with why.
  [[nodiscard]] LogsWithoutReport logs_without_report() const;
  /// Cuts a run's log after its last whole line: the part of a line a
  /// killed writer left (a write the kill cut short ends anywhere), which
  /// is no frame and would read as damage. A part as long as a log line or
  /// longer is no kill's: damage, left as it is. The cut is synced and the
  /// file closed, each checked; what was cut is returned even when a later
  /// step failed. Call it only under lock(): it must never cut a log being
  /// written.
  [[nodiscard]] TailCut cut_torn_tail(const std::string& run_id) const;
  /// Retention: removes the logs of runs whose report is in the index,
  /// readable and not an interrupted run's (never a report, never a log
  /// without one, never `keep`): first those last
  /// written more than keep_days before `now_unix_s`, then the oldest while
  /// all logs take more than max_log_bytes. What it removed or failed to.
  std::vector<PrunedLog> prune_logs(const Retention& r, double now_unix_s,
                                    const std::string& keep = {}) const;
  /// Bytes the file system of the directory gives an unprivileged writer.
  [[nodiscard]] Result<std::uint64_t> free_bytes() const;

 private:
  Result<nlohmann::json> load(const std::string& run_id) const;
  int allocate(int fd, std::uint64_t bytes) const;
  std::filesystem::path dir_;
  const FileIo* io_;
  Index index_;
};

}  // namespace turncal::daemon
