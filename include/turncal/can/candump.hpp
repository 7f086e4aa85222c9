// candump log files (`candump -l` format), classic and FD:
//   (1700000000.123456) vcan0 123#DEADBEEF
//   (1700000000.123456) vcan0 12345678#R
//   (1700000000.123456) vcan0 123##1112233
// Written with six decimals, which bookworm's canplayer (can-utils 2020.11)
// needs; read with any number of decimals. A malformed line is an error with
// its line number, never a silent skip.
#pragma once

#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "turncal/can/frame.hpp"
#include "turncal/result.hpp"

namespace turncal::can {

struct LogRecord {
  std::int64_t time_ns = 0;  ///< timestamp, ns since the Unix epoch (us resolution in files)
  std::string interface;
  Frame frame;
};

/// Parses one log line (no trailing newline). Pure; the error has no position.
Result<LogRecord> parse_log_line(std::string_view line);
/// Same, filling `out` in place (no allocation once `out.interface` has capacity).
Status parse_log_line(std::string_view line, LogRecord& out);

namespace detail {
/// The parse of any line, byte by byte: what parse_log_line gives, which
/// takes a line as candump writes it ("(%010d.%06d) name ID#DATA", a
/// classic data frame) a faster way first and any other this way.
Status parse_log_line_careful(std::string_view line, LogRecord& out);
/// The faster way alone: true when the line is as candump writes it and
/// `out` holds it; false (and `out` untouched) for any other.
bool parse_usual_line(std::string_view line, LogRecord& out);
}  // namespace detail

/// Longest line format_log_line can produce (FD frame, 29-bit id, 15-char name).
inline constexpr std::size_t kMaxLogLine = 200;
/// Formats one line with a trailing '\n' into `buf`; returns its length.
std::size_t format_log_line(const LogRecord& record, char* buf, std::size_t size);
std::string format_log_line(const LogRecord& record);

/// Streaming reader over a file descriptor or a FILE path; buffered, one line
/// at a time.
class LogReader {
 public:
  /// Opens `path` ("-" for standard input).
  static Result<LogReader> open(const std::string& path);
  /// Reads from an already open descriptor (not closed by the reader).
  static LogReader from_fd(int fd, std::string name);
  LogReader(LogReader&&) noexcept;
  LogReader& operator=(LogReader&&) noexcept;
  LogReader(const LogReader&) = delete;
  LogReader& operator=(const LogReader&) = delete;
  ~LogReader();

  /// Next record; std::nullopt at end of file. Blank lines are skipped; any
  /// other unparseable line is an error naming file and line.
  Result<std::optional<LogRecord>> next();
  /// Same, into `out`; returns false at end of file.
  Result<bool> next(LogRecord& out);
  [[nodiscard]] std::uint64_t line_number() const { return line_; }

 private:
  LogReader(int fd, bool owned, std::string name);
  bool fill();
  int fd_ = -1;
  bool owned_ = false;
  bool eof_ = false;
  std::string name_;
  std::vector<char> buf_;
  std::size_t begin_ = 0, end_ = 0;
  std::uint64_t line_ = 0;
  int read_errno_ = 0;
};

/// Buffered writer; flush() hands the data to the kernel, sync() also fsyncs.
class LogWriter {
 public:
  /// Creates or truncates (append=false) or appends to `path`.
  static Result<LogWriter> open(const std::string& path, bool append = false);
  LogWriter(LogWriter&&) noexcept;
  LogWriter& operator=(LogWriter&&) noexcept;
  LogWriter(const LogWriter&) = delete;
  LogWriter& operator=(const LogWriter&) = delete;
  ~LogWriter();

  Status write(const LogRecord& record);
  Status flush();
  Status sync();
  Status close();
  [[nodiscard]] std::uint64_t records() const { return records_; }
  /// Bytes of the records so far (in the file and still buffered).
  [[nodiscard]] std::uint64_t bytes() const { return pos_ + buf_.size(); }
  /// The file's descriptor (an fsync off the caller's thread); -1 closed.
  [[nodiscard]] int fd() const { return fd_; }
  /// Whole lines the file has taken (written, not only buffered). After a
  /// failed write the file is cut back to its last whole line, so it reads
  /// to its end, and every later write or flush fails the same way.
  [[nodiscard]] std::uint64_t records_written() const { return written_; }

 private:
  explicit LogWriter(int fd) : fd_(fd) {}
  int fd_ = -1;
  std::vector<char> buf_;
  std::uint64_t records_ = 0;
  std::uint64_t written_ = 0;
  std::uint64_t pos_ = 0;    ///< bytes in the file
  std::uint64_t whole_ = 0;  ///< bytes up to its last whole line
  bool failed_ = false;      ///< a write failed: the file ends at a whole line, nothing more goes
};

}  // namespace turncal::can
