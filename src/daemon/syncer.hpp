// fsync off the event loop. A phase's end is put on disk (the log up to
// there survives a power cut) without holding up the loop: an fsync that
// waits for a slow disk or a journal commit would hold the heartbeat, and
// the first phase end is the start of the turn. One thread; requests while
// an fsync runs are merged into the next. The loop hears of a failure on
// its next look (take_error), and waits for the thread before it closes
// the file (wait_idle), so no fsync ever lands on a reused descriptor.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <thread>

namespace turncal::daemon {

class Syncer {
 public:
  /// `fsync` is the system call, or a test's.
  explicit Syncer(int (*fsync)(int fd));
  ~Syncer();
  Syncer(const Syncer&) = delete;
  Syncer& operator=(const Syncer&) = delete;

  /// Asks for an fsync of `fd`; returns at once. `mark` (the log's line
  /// count when asked) is what synced() gives once that fsync succeeded.
  void request(int fd, std::uint64_t mark = 0);
  /// The mark of the last request whose fsync succeeded (0: none yet): how
  /// far the file is surely on disk.
  [[nodiscard]] std::uint64_t synced() const;
  /// A new file: synced() is 0 again (after wait_idle on the last one).
  void new_file();
  /// The errno of the first fsync that failed since the last call; 0: none.
  int take_error();
  /// Returns when no fsync is asked for or under way.
  void wait_idle();
  /// fsyncs done (a test's view).
  [[nodiscard]] unsigned long done() const;

 private:
  void run();
  int (*fsync_)(int);
  mutable std::mutex m_;
  std::condition_variable wake_, idle_;
  int want_fd_ = -1;  ///< asked for, not yet begun
  std::uint64_t want_mark_ = 0;
  std::uint64_t synced_ = 0;
  bool failed_ = false;  ///< an fsync of this file failed: synced_ stays where it was
  bool busy_ = false;
  bool stop_ = false;
  int error_ = 0;
  unsigned long done_ = 0;
  std::thread thread_;  ///< started in the constructor, with every signal blocked
};

}  // namespace turncal::daemon
