#include "turncal/can/candump.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
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

/// A frame's data zeroed from byte `from` (0 or 8) by 8-byte stores,
/// written out: as a memset, a loop or an array copy it compiles to a
/// string store, slow to start, a fifth of a line's parse.
void zero_data_from(Frame& f, std::size_t from) {
  static_assert(kMaxFdLen == 64);
  constexpr std::uint64_t kZero = 0;
  std::uint8_t* d = f.data.data();
  if (from == 0) std::memcpy(d, &kZero, 8);
  std::memcpy(d + 8, &kZero, 8);
  std::memcpy(d + 16, &kZero, 8);
  std::memcpy(d + 24, &kZero, 8);
  std::memcpy(d + 32, &kZero, 8);
  std::memcpy(d + 40, &kZero, 8);
  std::memcpy(d + 48, &kZero, 8);
  std::memcpy(d + 56, &kZero, 8);
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
  zero_data_from(f, 0);
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

/// Bytes that end an interface name: white space, control characters, DEL,
/// '/' and ':' (Linux's dev_valid_name refuses them; the space is the end).
constexpr std::array<bool, 256> kNameStop = [] {
  std::array<bool, 256> t{};
  for (int c = 0; c < 256; ++c)
    t[static_cast<std::size_t>(c)] = c <= 0x20 || c == 0x7F || c == '/' || c == ':';
  return t;
}();

std::uint64_t load8(const char* p) {
  std::uint64_t w = 0;
  std::memcpy(&w, p, sizeof w);
  return w;
}

/// True when each of the 8 bytes of `w` is an ASCII digit.
bool eight_digits(std::uint64_t w) {
  return ((w & 0xF0F0F0F0F0F0F0F0u) | (((w + 0x0606060606060606u) & 0xF0F0F0F0F0F0F0F0u) >> 4)) ==
         0x3333333333333333u;
}

/// The value of 8 ASCII digits loaded little-endian (the first, most
/// significant, in the low byte): pairs, then fours, then the eight.
std::uint64_t eight_digits_value(std::uint64_t w) {
  w -= 0x3030303030303030u;
  w = (w * 10 + (w >> 8)) & 0x00FF00FF00FF00FFu;    // d0d1, d2d3, d4d5, d6d7
  w = (w * 100 + (w >> 16)) & 0x0000FFFF0000FFFFu;  // d0..d3, d4..d7
  return (w * 10000 + (w >> 32)) & 0xFFFFFFFFu;     // d0..d7
}

/// The 4 bytes that 8 ASCII hex digits loaded little-endian give (the
/// first digit the high nibble of the low byte); false when any is none.
/// Each byte is tested against the ranges at once: with its top bit clear,
/// adding 0x80 - lo sets it from lo on, adding 0x7F - hi from past hi on,
/// and no byte carries into the next. A byte with its top bit set is in
/// neither range (its sums wrap), so the word is refused whatever it
/// carried into the byte after it.
bool eight_hex_digits(std::uint64_t w, std::uint32_t& out) {
  constexpr std::uint64_t kOnes = 0x0101010101010101u;
  constexpr std::uint64_t kTop = 0x80 * kOnes;
  const std::uint64_t l = w | (0x20 * kOnes);  // 'A'..'F' as 'a'..'f'
  const std::uint64_t digit = (w + (0x80 - '0') * kOnes) & ~(w + (0x7F - '9') * kOnes);
  const std::uint64_t alpha = (l + (0x80 - 'a') * kOnes) & ~(l + (0x7F - 'f') * kOnes);
  if (((digit | alpha) & kTop) != kTop) return false;
  // a digit's value is its low nibble; a letter's its low nibble + 9
  const std::uint64_t nib = (w & (0x0F * kOnes)) + ((alpha & kTop) >> 7) * 9;
  std::uint64_t x = ((nib << 4) | (nib >> 8)) & 0x00FF00FF00FF00FFu;  // bytes 0, 2, 4, 6
  x = (x | (x >> 8)) & 0x0000FFFF0000FFFFu;
  out = static_cast<std::uint32_t>(x | (x >> 16));
  return true;
}

/// A line as candump and format_log_line write it: "(" 10 digits "." 6
/// digits ") " name " " 3 or 8 hex digits "#" hex pairs, a classic data
/// frame. True when the line is one and `out` holds it; false for anything
/// else (`out` then untouched: it is written only once the whole line has
/// passed), which the careful parse reads or refuses with its column.
}  // namespace

bool detail::parse_usual_line(std::string_view line, LogRecord& out) {
  if constexpr (std::endian::native != std::endian::little) return false;
  const std::size_t n = line.size();
  const char* p = line.data();
  // "(" 10 + "." 6 ") " and at least "x 123#"
  if (n < 26 || p[0] != '(' || p[11] != '.' || p[18] != ')' || p[19] != ' ') return false;
  const std::uint64_t s8 = load8(p + 1);
  const std::uint64_t f6 = (load8(p + 12) << 16) | 0x3030u;  // "00" and the 6 digits
  const auto d9 = static_cast<unsigned>(p[9] - '0'), d10 = static_cast<unsigned>(p[10] - '0');
  if (!eight_digits(s8) || !eight_digits(f6) || d9 > 9 || d10 > 9) return false;
  const auto sec = static_cast<std::int64_t>(eight_digits_value(s8) * 100 + d9 * 10 + d10);
  constexpr std::int64_t kMaxSeconds = INT64_MAX / 1'000'000'000 - 1;
  if (sec > kMaxSeconds) return false;
  std::size_t i = 20;
  const std::size_t name_begin = i;
  while (i < n && !kNameStop[static_cast<unsigned char>(p[i])]) ++i;
  const std::size_t name_len = i - name_begin;
  if (i >= n || p[i] != ' ' || name_len == 0 || name_len > 15) return false;
  ++i;
  // the identifier: 3 hex digits, or 8 of an extended one (no error frame)
  std::size_t hash = 0;
  if (i + 3 < n && p[i + 3] == '#')
    hash = i + 3;
  else if (i + 8 < n && p[i + 8] == '#')
    hash = i + 8;  // a '#' before it is no hex digit: refused below
  else
    return false;
  std::uint32_t id = 0;
  int bad = 0;
  for (std::size_t k = i; k < hash; ++k) {
    const int h = hex_value(p[k]);
    bad |= h;
    id = (id << 4) | static_cast<std::uint32_t>(h & 0xF);
  }
  const bool extended = hash - i == 8;
  if (bad < 0 || (extended ? id > kExtIdMask : id > kStdIdMask)) return false;
  // hex pairs to the end: at most 8, nothing else
  const std::size_t digits = n - hash - 1;
  if (digits % 2 != 0 || digits > 2 * kMaxClassicLen) return false;
  Frame& f = out.frame;
  const char* d = p + hash + 1;
  std::uint64_t data = 0;
  if (digits == 2 * kMaxClassicLen) {  // 8 bytes, most frames: 8 digits at a time
    std::uint32_t lo = 0, hi = 0;
    if (!eight_hex_digits(load8(d), lo) || !eight_hex_digits(load8(d + 8), hi)) return false;
    data = lo | (static_cast<std::uint64_t>(hi) << 32);
  } else {
    for (std::size_t k = 0; k < digits / 2; ++k) {
      const int h = hex_value(d[2 * k]), l = hex_value(d[2 * k + 1]);
      bad |= h | l;
      data |= static_cast<std::uint64_t>((h << 4) | (l & 0xF)) << (8 * k);
    }
  }
  if (bad < 0) return false;
  // whole and usual: the record, as the careful parse would give it
  out.time_ns = sec * 1'000'000'000 + static_cast<std::int64_t>(eight_digits_value(f6)) * 1000;
  if (out.interface.size() != name_len ||
      std::memcmp(out.interface.data(), p + name_begin, name_len) != 0)
    out.interface.assign(p + name_begin, name_len);
  f.id = id;
  f.len = static_cast<std::uint8_t>(digits / 2);
  f.extended = extended;
  f.remote = f.fd = f.brs = f.esi = f.error = false;
  std::memcpy(f.data.data(), &data, 8);  // little endian: byte k is data's k-th
  zero_data_from(f, 8);
  return true;
}

Status parse_log_line(std::string_view line, LogRecord& out) {
  if (detail::parse_usual_line(line, out)) return Status{Ok{}};
  return detail::parse_log_line_careful(line, out);
}

Status detail::parse_log_line_careful(std::string_view line, LogRecord& out) {
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
