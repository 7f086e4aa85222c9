// A candump log read and parsed on a thread of its own, ahead of the one
// that takes its records: a replay's parsing (a third of its work on a
// two-hour log) then runs beside the sequencer and the filter. What it
// gives is what can::LogReader gives, in the same order, its error and
// line numbers included.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "turncal/can/candump.hpp"
#include "turncal/result.hpp"

namespace turncal::run {

class ReadAheadLogReader {
 public:
  explicit ReadAheadLogReader(can::LogReader reader);
  /// Stops the reading thread and waits for it: for the batch it is
  /// parsing, or for a read that blocks (a pipe whose writer is still open).
  ~ReadAheadLogReader();
  ReadAheadLogReader(const ReadAheadLogReader&) = delete;
  ReadAheadLogReader& operator=(const ReadAheadLogReader&) = delete;

  /// The next record, nullptr at the end (valid until the next call), as
  /// can::LogReader::next gives it; the reader's error where a line does
  /// not parse or the file cannot be read, and on every call after: the log
  /// ends there, where can::LogReader goes on to the next line. What the
  /// reading thread threw (out of memory) is thrown here, after the
  /// records it read.
  Result<const can::LogRecord*> next();
  /// The line of the record last given; after the end or an error, the
  /// reader's last line, as can::LogReader::line_number.
  [[nodiscard]] std::uint64_t line_number() const { return line_; }

 private:
  struct Batch {
    std::vector<can::LogRecord> records;
    std::vector<std::uint64_t> lines;  ///< each record's line
    std::uint64_t last_line = 0;       ///< the reader's line at the batch's end
    std::optional<Error> error;
    bool end = false;
  };
  void produce();

  can::LogReader reader_;
  std::mutex m_;
  std::condition_variable cv_;
  std::deque<Batch> full_;   ///< parsed, in order
  std::vector<Batch> free_;  ///< taken, for the thread to fill again
  bool stop_ = false;
  std::exception_ptr thrown_;  ///< what ended the reading thread, if it threw
  Batch cur_;
  std::size_t at_ = 0;
  bool have_cur_ = false;
  std::uint64_t line_ = 0;
  std::thread thread_;  ///< last: started once the rest is made
};

}  // namespace turncal::run
