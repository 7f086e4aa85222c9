#include "turncal/can/candump.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>

namespace turncal::can {
namespace {

constexpr std::uint32_t kErrFlag = 0x20000000u;  // CAN_ERR_FLAG as candump prints it
constexpr std::size_t kReadChunk = 1 << 16;

/// Each byte's value as a hex digit, -1 where it is none: one load a digit
/// rather than three range tests (a two-hour log has 100 million digits).
constexpr std::array<std::int8_t, 256> kHexValue = [] {
  std::array<std::int8_t, 256> t{};
  for (int c = 0; c < 256; ++c)
    t[static_cast<std::size_t>(c)] = static_cast<std::int8_t>(c >= '0' && c <= '9'   ? c - '0'
                                                              : c >= 'a' && c <= 'f' ? c - 'a' + 10
                                                              : c >= 'A' && c <= 'F' ? c - 'A' + 10
                                                                                     : -1);
  return t;
}();

int hex_value(char c) {
  return kHexValue[static_cast<unsigned char>(c)];
}

Error line_error(std::string what, std::size_t column) {
  return make_error(std::move(what), SourcePos{{}, 0, static_cast<std::uint32_t>(column + 1)});
}

/// Parses the frame part "ID#DATA", "ID#R[len]", "ID##FDATA".
Status parse_frame(std::string_view s, std::size_t col0, Frame& f) {
  // a new frame, field by field: `f = Frame{}` compiles to a string store
  // of its 75 bytes, slow to start, a fifth of this function's time
  f.id = 0;
  f.len = 0;
  f.extended = f.remote = f.fd = f.brs = f.esi = f.error = false;
  // the payload zeroed by eight 8-byte stores, written out: as a memset, a
  // loop or an array copy it compiles to the string store again
  static_assert(kMaxFdLen == 64);
  constexpr std::uint64_t kZero = 0;
  std::uint8_t* d = f.data.data();
  std::memcpy(d, &kZero, 8);
  std::memcpy(d + 8, &kZero, 8);
  std::memcpy(d + 16, &kZero, 8);
  std::memcpy(d + 24, &kZero, 8);
  std::memcpy(d + 32, &kZero, 8);
  std::memcpy(d + 40, &kZero, 8);
  std::memcpy(d + 48, &kZero, 8);
  std::memcpy(d + 56, &kZero, 8);
  std::size_t i = 0;
  std::uint32_t id = 0;
  while (i < s.size() && s[i] != '#') {
    const int h = hex_value(s[i]);
    if (h < 0 || i >= 8) return line_error("bad CAN identifier", col0 + i);
    id = (id << 4) | static_cast<std::uint32_t>(h);
    ++i;
  }
  if (i == s.size()) return line_error("missing '#' after the CAN identifier", col0 + i);
  if (i == 3) {
    if (id > kStdIdMask) return line_error("11-bit identifier out of range", col0);
    f.id = id;
  } else if (i == 8) {
    if (id & kErrFlag) {
      f.error = true;
      f.id = id & kExtIdMask;
    } else if (id > kExtIdMask) {
      return line_error("29-bit identifier out of range", col0);
    } else {
      f.extended = true;
      f.id = id;
    }
  } else {
    return line_error("CAN identifier must have 3 or 8 hex digits", col0);
  }
  ++i;  // '#'
  std::size_t max_len = kMaxClassicLen;
  if (i < s.size() && s[i] == '#') {
    if (f.error) return line_error("error frame cannot be CAN FD", col0 + i);
    ++i;
    if (i >= s.size()) return line_error("missing CAN FD flags", col0 + i);
    const int flags = hex_value(s[i]);
    if (flags < 0) return line_error("bad CAN FD flags", col0 + i);
    f.fd = true;
    f.brs = (flags & 1) != 0;
    f.esi = (flags & 2) != 0;
    max_len = kMaxFdLen;
    ++i;
  } else if (i < s.size() && (s[i] == 'R' || s[i] == 'r')) {
    f.remote = true;
    ++i;
    if (i < s.size()) {
      const int n = hex_value(s[i]);
      if (n < 0 || n > 8 || i + 1 != s.size())
        return line_error("bad remote frame length", col0 + i);
      f.len = static_cast<std::uint8_t>(n);
    }
    return Status{Ok{}};
  }
  std::size_t len = 0;
  while (i < s.size()) {
    if (s[i] == '.') {
      ++i;
      continue;
    }
    if (s[i] == '_' && !f.fd) {  // len8_dlc suffix of classic frames: accepted, not kept
      if (len != 8 || i + 2 != s.size() || hex_value(s[i + 1]) < 9)
        return line_error("bad DLC suffix", col0 + i);
      break;
    }
    if (i + 1 >= s.size()) return line_error("odd number of hex digits in the data", col0 + i);
    const int hi = hex_value(s[i]), lo = hex_value(s[i + 1]);
    if (hi < 0 || lo < 0) return line_error("bad hex digit in the data", col0 + i);
    if (len >= max_len) return line_error("too many data bytes", col0 + i);
    f.data[len++] = static_cast<std::uint8_t>((hi << 4) | lo);
    i += 2;
  }
  if (f.fd && !is_valid_fd_len(len)) return line_error("invalid CAN FD payload length", col0 + i);
  f.len = static_cast<std::uint8_t>(len);
  return Status{Ok{}};
}

}  // namespace

Status parse_log_line(std::string_view line, LogRecord& out) {
  while (!line.empty() && (line.back() == '\r' || line.back() == ' ' || line.back() == '\t'))
    line.remove_suffix(1);
  std::size_t i = 0;
  if (line.empty() || line[0] != '(') return line_error("expected '(' and a timestamp", 0);
  ++i;
  std::int64_t sec = 0;
  std::size_t digits = 0;
  constexpr std::int64_t kMaxSeconds = INT64_MAX / 1'000'000'000 - 1;  // year 2262
  while (i < line.size() && line[i] >= '0' && line[i] <= '9') {
    sec = sec * 10 + (line[i] - '0');
    if (++digits > 10 || sec > kMaxSeconds) return line_error("timestamp out of range", i);
    ++i;
  }
  if (digits == 0 || i >= line.size() || line[i] != '.')
    return line_error("timestamp must be seconds.fraction", i);
  ++i;
  std::int64_t frac = 0;
  std::size_t fdigits = 0;
  while (i < line.size() && line[i] >= '0' && line[i] <= '9') {
    if (fdigits < 9) frac = frac * 10 + (line[i] - '0');
    ++fdigits;
    ++i;
  }
  if (fdigits == 0 || fdigits > 9) return line_error("timestamp fraction needs 1 to 9 digits", i);
  for (std::size_t k = fdigits; k < 9; ++k) frac *= 10;
  if (i >= line.size() || line[i] != ')') return line_error("expected ')' after the timestamp", i);
  ++i;
  if (i >= line.size() || line[i] != ' ') return line_error("expected a space", i);
  ++i;
  const std::size_t name_begin = i;
  while (i < line.size() && line[i] != ' ') {
    // Linux interface names (dev_valid_name): no '/', ':', white space or NUL
    const auto c = static_cast<unsigned char>(line[i]);
    if (c <= 0x20 || c == 0x7F || c == '/' || c == ':')
      return line_error("bad character in the interface name", i);
    ++i;
  }
  if (i == name_begin || i - name_begin > 15)
    return line_error("interface name must have 1 to 15 characters", name_begin);
  out.interface.assign(line.substr(name_begin, i - name_begin));
  if (i >= line.size()) return line_error("missing frame", i);
  ++i;
  out.time_ns = sec * 1'000'000'000 + frac;
  return parse_frame(line.substr(i), i, out.frame);
}

Result<LogRecord> parse_log_line(std::string_view line) {
  LogRecord r;
  auto st = parse_log_line(line, r);
  if (!st) return std::move(st).error();
  return r;
}

std::size_t format_log_line(const LogRecord& r, char* buf, std::size_t size) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  char tmp[kMaxLogLine];
  const std::int64_t us = r.time_ns / 1000;
  const int n =
      std::snprintf(tmp, sizeof tmp, "(%010lld.%06lld) ", static_cast<long long>(us / 1'000'000),
                    static_cast<long long>(us % 1'000'000));
  std::size_t p = n > 0 ? static_cast<std::size_t>(n) : 0;
  const std::size_t name_len = std::min<std::size_t>(r.interface.size(), 15);
  std::memcpy(tmp + p, r.interface.data(), name_len);
  p += name_len;
  tmp[p++] = ' ';
  const Frame& f = r.frame;
  if (f.error || f.extended) {
    const std::uint32_t id = f.error ? (f.id & kExtIdMask) | kErrFlag : f.id & kExtIdMask;
    for (int s = 28; s >= 0; s -= 4) tmp[p++] = kHex[(id >> s) & 0xF];
  } else {
    for (int s = 8; s >= 0; s -= 4) tmp[p++] = kHex[(f.id >> s) & 0xF];
  }
  tmp[p++] = '#';
  if (f.fd) {
    tmp[p++] = '#';
    tmp[p++] = kHex[(f.brs ? 1 : 0) | (f.esi ? 2 : 0)];
  } else if (f.remote) {
    tmp[p++] = 'R';
  }
  if (!f.remote) {
    for (std::size_t k = 0; k < f.len && k < kMaxFdLen; ++k) {
      tmp[p++] = kHex[f.data[k] >> 4];
      tmp[p++] = kHex[f.data[k] & 0xF];
    }
  }
  tmp[p++] = '\n';
  if (p > size) return 0;
  std::memcpy(buf, tmp, p);
  return p;
}

std::string format_log_line(const LogRecord& record) {
  char buf[kMaxLogLine];
  return std::string(buf, format_log_line(record, buf, sizeof buf));
}

// ---- reader ----

LogReader::LogReader(int fd, bool owned, std::string name)
    : fd_(fd), owned_(owned), name_(std::move(name)), buf_(kReadChunk * 2) {}
LogReader::LogReader(LogReader&& o) noexcept
    : fd_(std::exchange(o.fd_, -1)),
      owned_(o.owned_),
      eof_(o.eof_),
      name_(std::move(o.name_)),
      buf_(std::move(o.buf_)),
      begin_(o.begin_),
      end_(o.end_),
      line_(o.line_),
      read_errno_(o.read_errno_) {}
LogReader& LogReader::operator=(LogReader&& o) noexcept {
  if (this != &o) {
    if (owned_ && fd_ >= 0) ::close(fd_);
    fd_ = std::exchange(o.fd_, -1);
    owned_ = o.owned_;
    eof_ = o.eof_;
    name_ = std::move(o.name_);
    buf_ = std::move(o.buf_);
    begin_ = o.begin_;
    end_ = o.end_;
    line_ = o.line_;
    read_errno_ = o.read_errno_;
  }
  return *this;
}
LogReader::~LogReader() {
  if (owned_ && fd_ >= 0) ::close(fd_);
}

Result<LogReader> LogReader::open(const std::string& path) {
  if (path == "-") return LogReader(0, false, "<stdin>");
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return make_error(path + ": cannot open: " + std::strerror(errno));
  return LogReader(fd, true, path);
}

LogReader LogReader::from_fd(int fd, std::string name) {
  return LogReader(fd, false, std::move(name));
}

bool LogReader::fill() {
  if (eof_) return false;
  if (begin_ > 0) {
    std::memmove(buf_.data(), buf_.data() + begin_, end_ - begin_);
    end_ -= begin_;
    begin_ = 0;
  }
  if (buf_.size() - end_ < kReadChunk) buf_.resize(buf_.size() * 2);
  for (;;) {
    const ssize_t n = ::read(fd_, buf_.data() + end_, buf_.size() - end_);
    if (n > 0) {
      end_ += static_cast<std::size_t>(n);
      return true;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) read_errno_ = errno;
    eof_ = true;
    return false;
  }
}

Result<bool> LogReader::next(LogRecord& out) {
  for (;;) {
    const char* start = buf_.data() + begin_;
    const void* nl = std::memchr(start, '\n', end_ - begin_);
    std::string_view line;
    if (nl != nullptr) {
      line =
          std::string_view(start, static_cast<std::size_t>(static_cast<const char*>(nl) - start));
      begin_ += line.size() + 1;
    } else if (fill()) {
      continue;
    } else if (read_errno_ != 0) {
      return make_error(name_ + ": read error: " + std::strerror(read_errno_));
    } else if (begin_ < end_) {  // last line without a newline
      line = std::string_view(start, end_ - begin_);
      begin_ = end_;
    } else {
      return false;
    }
    ++line_;
    if (line.find_first_not_of(" \t\r") == std::string_view::npos) continue;
    auto st = parse_log_line(line, out);
    if (!st) {
      Error e = std::move(st).error();
      e.where.file = name_;
      e.where.line = static_cast<std::uint32_t>(line_);
      return e;
    }
    return true;
  }
}

Result<std::optional<LogRecord>> LogReader::next() {
  LogRecord r;
  auto got = next(r);
  if (!got) return std::move(got).error();
  if (!*got) return std::optional<LogRecord>{};
  return std::optional<LogRecord>{std::move(r)};
}

// ---- writer ----

LogWriter::LogWriter(LogWriter&& o) noexcept
    : fd_(std::exchange(o.fd_, -1)),
      buf_(std::move(o.buf_)),
      records_(o.records_),
      written_(o.written_),
      pos_(o.pos_),
      whole_(o.whole_),
      failed_(o.failed_) {}
LogWriter& LogWriter::operator=(LogWriter&& o) noexcept {
  if (this != &o) {
    (void)close();
    fd_ = std::exchange(o.fd_, -1);
    buf_ = std::move(o.buf_);
    records_ = o.records_;
    written_ = o.written_;
    pos_ = o.pos_;
    whole_ = o.whole_;
    failed_ = o.failed_;
  }
  return *this;
}
LogWriter::~LogWriter() {
  (void)close();
}

Result<LogWriter> LogWriter::open(const std::string& path, bool append) {
  const int flags = O_WRONLY | O_CREAT | O_CLOEXEC | (append ? O_APPEND : O_TRUNC);
  const int fd = ::open(path.c_str(), flags, 0640);
  if (fd < 0) return make_error(path + ": cannot open for writing: " + std::strerror(errno));
  LogWriter w(fd);
  if (append) {
    const off_t end = ::lseek(fd, 0, SEEK_END);
    if (end < 0) {
      const int err = errno;
      ::close(fd);
      w.fd_ = -1;
      return make_error(path + ": cannot seek: " + std::strerror(err));
    }
    w.pos_ = w.whole_ = static_cast<std::uint64_t>(end);
  }
  w.buf_.reserve(kReadChunk);
  return w;
}

Status LogWriter::write(const LogRecord& record) {
  if (fd_ < 0) return make_error("log writer is closed");
  if (failed_) return make_error("log write failed earlier");
  char line[kMaxLogLine];
  const std::size_t n = format_log_line(record, line, sizeof line);
  buf_.insert(buf_.end(), line, line + n);
  ++records_;
  if (buf_.size() >= kReadChunk) return flush();
  return Status{Ok{}};
}

Status LogWriter::flush() {
  if (failed_) return make_error("log write failed earlier");
  std::size_t done = 0;
  while (done < buf_.size()) {
    const ssize_t n = ::write(fd_, buf_.data() + done, buf_.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = n == 0 ? EIO : errno;
      failed_ = true;
      buf_.clear();
      // a line cut by the failure would read as damage: the file ends at
      // its last whole line
      const bool cut = pos_ == whole_ || ::ftruncate(fd_, static_cast<off_t>(whole_)) == 0;
      return make_error(std::string("log write failed: ") + std::strerror(err) +
                        (cut ? "" : " (and the last line could not be cut off)"));
    }
    const auto first = buf_.begin() + static_cast<std::ptrdiff_t>(done);
    const auto last = first + n;
    written_ += static_cast<std::uint64_t>(std::count(first, last, '\n'));
    const auto nl =
        std::find(std::make_reverse_iterator(last), std::make_reverse_iterator(first), '\n');
    if (nl != std::make_reverse_iterator(first))
      whole_ = pos_ + static_cast<std::uint64_t>(nl.base() - first);
    pos_ += static_cast<std::uint64_t>(n);
    done += static_cast<std::size_t>(n);
  }
  buf_.clear();
  return Status{Ok{}};
}

Status LogWriter::sync() {
  auto st = flush();
  if (!st) return st;
  if (::fsync(fd_) != 0)
    return make_error(std::string("log fsync failed: ") + std::strerror(errno));
  return Status{Ok{}};
}

Status LogWriter::close() {
  if (fd_ < 0) return Status{Ok{}};
  auto st = flush();
  const bool closed = ::close(fd_) == 0;
  const int err = errno;
  fd_ = -1;
  if (st && !closed) return make_error(std::string("log close failed: ") + std::strerror(err));
  return st;
}

}  // namespace turncal::can
