#include <doctest/doctest.h>
#include <sys/resource.h>
#include <unistd.h>

#include <csignal>

#include <cstdio>
#include <filesystem>
#include <functional>
#include <optional>
#include <random>
#include <string>

#include "turncal/can/candump.hpp"

using namespace turncal::can;

TEST_SUITE("candump") {
  TEST_CASE("classic, extended, remote, FD and error frames parse") {
    SUBCASE("classic") {
      auto r = parse_log_line("(1700000000.123456) vcan0 123#DEADBEEF");
      REQUIRE(r.ok());
      CHECK(r->time_ns == 1700000000123456000);
      CHECK(r->interface == "vcan0");
      CHECK(r->frame.id == 0x123);
      CHECK_FALSE(r->frame.extended);
      CHECK(r->frame.len == 4);
      CHECK(r->frame.data[0] == 0xDE);
      CHECK(r->frame.data[3] == 0xEF);
    }
    SUBCASE("empty classic") {
      auto r = parse_log_line("(0000000001.000001) can1 7FF#");
      REQUIRE(r.ok());
      CHECK(r->frame.len == 0);
      CHECK(r->time_ns == 1000001000);
    }
    SUBCASE("extended") {
      auto r = parse_log_line("(1.5) vcan0 12345678#00");
      REQUIRE(r.ok());
      CHECK(r->frame.extended);
      CHECK(r->frame.id == 0x12345678);
      CHECK(r->time_ns == 1500000000);
    }
    SUBCASE("remote with length") {
      auto r = parse_log_line("(1.000000) vcan0 123#R3");
      REQUIRE(r.ok());
      CHECK(r->frame.remote);
      CHECK(r->frame.len == 3);
    }
    SUBCASE("FD with flags") {
      auto r = parse_log_line("(1.000000) vcan0 321##3000102030405060708090A0B");
      REQUIRE(r.ok());
      CHECK(r->frame.fd);
      CHECK(r->frame.brs);
      CHECK(r->frame.esi);
      CHECK(r->frame.len == 12);
      CHECK(r->frame.data[11] == 0x0B);
    }
    SUBCASE("error frame") {
      auto r = parse_log_line("(1.000000) vcan0 20000040#0000000000000000");
      REQUIRE(r.ok());
      CHECK(r->frame.error);
      CHECK(r->frame.id == 0x40);
    }
    SUBCASE("dotted data and nine decimals") {
      auto r = parse_log_line("(12.123456789) vcan0 123#11.22.33");
      REQUIRE(r.ok());
      CHECK(r->frame.len == 3);
      CHECK(r->time_ns == 12123456789);
    }
  }

  TEST_CASE("a record parsed into again holds the new frame alone, its unused bytes zero") {
    // the reader parses every line into the record it was given: nothing
    // of the line before (an FD frame's bytes, a flag) may stay
    LogRecord rec;
    REQUIRE(parse_log_line("(1.000000) vcan0 12345678##3" + std::string(128, 'A'), rec));
    REQUIRE(rec.frame.len == 64);
    REQUIRE(parse_log_line("(2.000000) vcan0 20000040#", rec));
    REQUIRE(rec.frame.error);
    REQUIRE(parse_log_line("(3.000000) vcan1 123#c0fFeE", rec));
    CHECK(rec.time_ns == 3'000'000'000);
    CHECK(rec.interface == "vcan1");
    CHECK(rec.frame.id == 0x123);
    CHECK(rec.frame.len == 3);
    CHECK_FALSE(rec.frame.extended);
    CHECK_FALSE(rec.frame.fd);
    CHECK_FALSE(rec.frame.brs);
    CHECK_FALSE(rec.frame.esi);
    CHECK_FALSE(rec.frame.error);
    CHECK_FALSE(rec.frame.remote);
    CHECK(rec.frame.data[0] == 0xC0);
    CHECK(rec.frame.data[1] == 0xFF);
    CHECK(rec.frame.data[2] == 0xEE);
    int nonzero = 0;
    for (std::size_t k = 3; k < rec.frame.data.size(); ++k) nonzero += rec.frame.data[k] != 0;
    CHECK(nonzero == 0);
    // a payload with dots, and one with a DLC suffix, each right after an
    // FD frame of 64 bytes: every byte past the payload zero
    for (const char* line :
         {"(4.000000) vcan1 123#11.22.33", "(5.000000) vcan1 123#0102030405060708_9"}) {
      CAPTURE(line);
      REQUIRE(parse_log_line("(1.000000) vcan0 12345678##3" + std::string(128, 'A'), rec));
      REQUIRE(parse_log_line(line, rec));
      CHECK(rec.frame.len == (line[21] == '1' ? 3 : 8));
      CHECK(rec.frame.data[rec.frame.len - 1] == (line[21] == '1' ? 0x33 : 0x08));
      int stale = 0;
      for (std::size_t k = rec.frame.len; k < rec.frame.data.size(); ++k)
        stale += rec.frame.data[k] != 0;
      CHECK(stale == 0);
    }
    // every byte value's hex digits, both cases, and what is none
    for (int b = 0; b < 256; ++b) {
      char line[64];
      std::snprintf(line, sizeof line, "(1.0) vcan0 123#%02x%02X", b, b);
      CAPTURE(line);
      REQUIRE(parse_log_line(line, rec));
      CHECK(rec.frame.data[0] == b);
      CHECK(rec.frame.data[1] == b);
    }
    for (const char c : std::string("gG:@/`~\x7f\xc3")) {
      const std::string line = std::string("(1.0) vcan0 123#0") + c;
      CAPTURE(line);
      CHECK_FALSE(parse_log_line(line, rec));
    }
  }

  TEST_CASE(
      "property: the usual lines' fast parse gives what the careful one gives, or leaves it") {
    // lines as the writer makes them, then spoilt a byte or three at a time
    // (a digit, a hex letter, a separator, a byte no line has, one taken
    // out or put in): whatever the parse gives, record or error with its
    // column, is the careful parse's, into a record that held another
    std::mt19937_64 rng(0x5eed'cafe);
    // (and the bytes next to the hex digits' ranges: / : @ G ` g, 0x10..0x19,
    // 0x41..0x46 and 0x61..0x66 with the top bit set)
    const std::string alphabet =
        std::string("0159aAfFgG#.() R_r:/\r\t\x7f\xff@`\x10\x19\xc1\xc6\xe1\xe6\xb0\xb9", 34) +
        '\0';
    int whole = 0, refused = 0, taken = 0;
    for (int trial = 0; trial < 60000; ++trial) {
      LogRecord r;
      r.time_ns = static_cast<std::int64_t>(rng() % 9'000'000'000'000'000'000ull);
      r.interface = std::string(1 + rng() % 15, 'c');
      for (char& c : r.interface) c = "canvx019_-"[rng() % 10];
      r.frame.extended = rng() % 4 == 0;
      r.frame.id = static_cast<std::uint32_t>(rng() & (r.frame.extended ? kExtIdMask : kStdIdMask));
      r.frame.len = static_cast<std::uint8_t>(rng() % 9);
      for (std::size_t k = 0; k < r.frame.len; ++k)
        r.frame.data[k] = static_cast<std::uint8_t>(rng());
      std::string line = format_log_line(r);
      line.pop_back();  // the newline
      const int spoils = static_cast<int>(rng() % 4);
      for (int k = 0; k < spoils && !line.empty(); ++k) {
        const std::size_t at = rng() % line.size();
        const char c = alphabet[rng() % alphabet.size()];
        switch (rng() % 3) {
          case 0:
            line[at] = c;
            break;
          case 1:
            line.erase(at, 1);
            break;
          default:
            line.insert(at, 1, c);
        }
      }
      CAPTURE(line);
      LogRecord fast, careful;
      for (LogRecord* was : {&fast, &careful}) {  // each held an FD frame of 64 bytes
        REQUIRE(parse_log_line("(1.000000) vcan0 12345678##3" + std::string(128, 'A'), *was));
      }
      const turncal::Status a = parse_log_line(line, fast);
      const turncal::Status b = detail::parse_log_line_careful(line, careful);
      REQUIRE(a.ok() == b.ok());
      // the faster way itself: it takes every line as the writer makes it,
      // and what it takes is the careful parse's record
      // and a line it does not take leaves the record as it was
      LogRecord usual;
      REQUIRE(parse_log_line("(2.500000) can1 1FFFFFFF##1" + std::string(96, 'C'), usual));
      const LogRecord sentinel = usual;
      const bool took = detail::parse_usual_line(line, usual);
      if (spoils == 0) CHECK(took);
      if (!took) {
        CHECK(usual.time_ns == sentinel.time_ns);
        CHECK(usual.interface == sentinel.interface);
        CHECK(usual.frame == sentinel.frame);
        CHECK(usual.frame.data == sentinel.frame.data);
      }
      if (took) {
        ++taken;
        REQUIRE(b.ok());
        CHECK(usual.time_ns == careful.time_ns);
        CHECK(usual.interface == careful.interface);
        CHECK(usual.frame.data == careful.frame.data);
        CHECK(usual.frame == careful.frame);
      }
      if (a.ok()) {
        ++whole;
        CHECK(fast.time_ns == careful.time_ns);
        CHECK(fast.interface == careful.interface);
        CHECK(fast.frame == careful.frame);
        CHECK(fast.frame.data == careful.frame.data);  // the bytes past the payload too
        if (spoils == 0) {
          CHECK(fast.time_ns == r.time_ns / 1000 * 1000);
          CHECK(fast.interface == r.interface);
          CHECK(fast.frame == r.frame);
        }
      } else {
        ++refused;
        CHECK(a.error().message == b.error().message);
        CHECK(a.error().where.column == b.error().where.column);
      }
    }
    // both ways taken often: lines read, lines refused
    CHECK(whole > 20000);
    CHECK(refused > 20000);
    CHECK(taken > 10000);
    // every byte value in every place of the 16 digits of an 8-byte frame,
    // and in the 3 of its identifier
    const std::string usual = "(1767225600.250000) vcan0 1Ab#0123456789aBcDeF";
    int read = 0;
    for (std::size_t at = usual.find(' ', 20) + 1; at < usual.size(); ++at) {
      if (usual[at] == '#') continue;
      for (int b = 0; b < 256; ++b) {
        std::string line = usual;
        line[at] = static_cast<char>(b);
        CAPTURE(line);
        LogRecord fast, careful;
        const turncal::Status a = parse_log_line(line, fast);
        const turncal::Status c = detail::parse_log_line_careful(line, careful);
        REQUIRE(a.ok() == c.ok());
        if (!a.ok()) continue;
        ++read;
        CHECK(fast.frame == careful.frame);
        CHECK(fast.frame.id == careful.frame.id);
      }
    }
    // the 22 hex digits (0-9, a-f, A-F) in each place but the identifier's
    // first (0-7: 0x7FF is the largest), and a second '#' after the first
    // (an FD frame of flags 1 and 7 bytes)
    CHECK(read == 18 * 22 + 8 + 1);
  }

  TEST_CASE("malformed lines are errors with a column") {
    const char* bad[] = {
        "",
        "1.0 vcan0 123#00",
        "(1.0 vcan0 123#00",
        "(1.) vcan0 123#00",
        "(1.0) vcan0",
        "(1.0) vcan0 12#00",
        "(1.0) vcan0 800#00",
        "(1.0) vcan0 123#0",
        "(1.0) vcan0 123#GG",
        "(1.0) vcan0 123#001122334455667788",
        "(1.0) vcan0 123##0"
        "00112233445566778899",  // 10 bytes: no FD length
        "(1.0) vcan0 123#R9",
        "(1.0) vcan0 40000000#00",
        "(1.0) averyveryverylongname 123#00",
        "(1.0) vcan0 123",
        "(17000000009.123456) vcan0 123#00",  // beyond int64 nanoseconds: found by fuzz_candump
        "(1.0) vc:an0 123#00",
    };
    for (const char* text : bad) {
      const std::string line = text;
      CAPTURE(line);
      auto r = parse_log_line(line);
      CHECK_FALSE(r.ok());
      if (!r.ok()) CHECK(r.error().where.column >= 1);
    }
  }

  TEST_CASE("a NUL in the interface name is refused (found by fuzz_candump)") {
    const std::string line("(1.0) v\0can0 123#00", 20);
    CHECK_FALSE(parse_log_line(line).ok());
  }

  TEST_CASE("format writes six decimals and reads back the same record") {
    std::mt19937_64 rng(20261123);
    for (int n = 0; n < 2000; ++n) {
      LogRecord rec;
      rec.time_ns = static_cast<std::int64_t>(rng() % 4'000'000'000'000'000'000ull / 1000 * 1000);
      rec.interface = (n % 2) ? "vcan0" : "can12";
      Frame& f = rec.frame;
      const auto kind = rng() % 4;
      f.extended = kind == 1;
      f.fd = kind == 2;
      f.remote = kind == 3 && (rng() % 2);
      f.id = static_cast<std::uint32_t>(rng()) & (f.extended ? kExtIdMask : kStdIdMask);
      static constexpr std::uint8_t kFdLens[] = {0, 1, 5, 8, 12, 16, 20, 24, 32, 48, 64};
      f.len = f.fd ? kFdLens[rng() % std::size(kFdLens)] : static_cast<std::uint8_t>(rng() % 9);
      f.brs = f.fd && (rng() % 2);
      f.esi = f.fd && (rng() % 2);
      if (!f.remote)
        for (std::size_t i = 0; i < f.len; ++i) f.data[i] = static_cast<std::uint8_t>(rng());
      const std::string line = format_log_line(rec);
      CAPTURE(line);
      REQUIRE(line.back() == '\n');
      CHECK(line[line.find('.') + 7] == ')');
      auto back = parse_log_line(std::string_view(line).substr(0, line.size() - 1));
      REQUIRE(back.ok());
      CHECK(back->time_ns == rec.time_ns);
      CHECK(back->interface == rec.interface);
      if (f.remote) {  // candump -l writes no length for remote frames
        CHECK(back->frame.remote);
        CHECK(back->frame.id == f.id);
      } else {
        CHECK(back->frame == f);
      }
    }
  }

  TEST_CASE("the writer and the streaming reader round trip a file") {
    const auto path =
        std::filesystem::temp_directory_path() / ("turncal-log-" + std::to_string(::getpid()));
    {
      auto w = LogWriter::open(path.string());
      REQUIRE(w.ok());
      for (int i = 0; i < 50000; ++i) {
        LogRecord r;
        r.time_ns = 1'700'000'000'000'000'000 + i * 2'500'000LL;
        r.interface = "vcan0";
        r.frame.id = static_cast<std::uint32_t>(0x100 + i % 7);
        r.frame.len = 8;
        for (int b = 0; b < 8; ++b)
          r.frame.data[static_cast<std::size_t>(b)] = static_cast<std::uint8_t>(i + b);
        REQUIRE(w->write(r).ok());
      }
      REQUIRE(w->sync().ok());
      CHECK(w->records() == 50000);
    }
    auto rd = LogReader::open(path.string());
    REQUIRE(rd.ok());
    LogRecord rec;
    int n = 0;
    for (;;) {
      auto got = rd->next(rec);
      REQUIRE(got.ok());
      if (!*got) break;
      CHECK(rec.frame.id == static_cast<std::uint32_t>(0x100 + n % 7));
      CHECK(rec.time_ns == 1'700'000'000'000'000'000 + n * 2'500'000LL);
      ++n;
    }
    CHECK(n == 50000);
    std::filesystem::remove(path);
  }

  TEST_CASE("a log whose file system refuses more ends at its last whole line, and says so") {
    // a real refusal from the kernel: the file size limit (EFBIG), as a full
    // disk refuses with ENOSPC, partway through a buffer
    const auto path =
        std::filesystem::temp_directory_path() / ("turncal-full-" + std::to_string(::getpid()));
    rlimit old{};
    REQUIRE(::getrlimit(RLIMIT_FSIZE, &old) == 0);
    const auto old_handler = std::signal(SIGXFSZ, SIG_IGN);
    rlimit small = old;
    small.rlim_cur = 100'003;  // not on a line boundary
    REQUIRE(::setrlimit(RLIMIT_FSIZE, &small) == 0);
    std::string error;
    std::uint64_t written = 0;
    {
      auto w = LogWriter::open(path.string());
      REQUIRE(w.ok());
      for (int i = 0; i < 50000 && error.empty(); ++i) {
        LogRecord r;
        r.time_ns = 1'700'000'000'000'000'000 + i * 2'500'000LL;
        r.interface = "vcan0";
        r.frame.id = 0x123;
        r.frame.len = 8;
        if (auto st = w->write(r); !st) error = st.error().describe();
      }
      if (error.empty())
        if (auto st = w->sync(); !st) error = st.error().describe();
      written = w->records_written();
      CHECK_FALSE(w->write(LogRecord{}).ok());  // nothing more goes
      CHECK_FALSE(w->flush().ok());
    }
    REQUIRE(::setrlimit(RLIMIT_FSIZE, &old) == 0);
    std::signal(SIGXFSZ, old_handler);
    CHECK(error.find("log write failed: File too large") == 0);
    CHECK(written > 1000);
    const auto size = std::filesystem::file_size(path);
    CHECK(size < 100'003);
    auto rd = LogReader::open(path.string());
    REQUIRE(rd.ok());
    LogRecord rec;
    std::uint64_t n = 0;
    for (;;) {
      auto got = rd->next(rec);
      REQUIRE_MESSAGE(got.ok(), got.error().describe());  // no half line at the end
      if (!*got) break;
      ++n;
    }
    CHECK(n == written);
    std::filesystem::remove(path);
  }

  TEST_CASE("a malformed line in a file is an error naming file and line") {
    const auto path =
        std::filesystem::temp_directory_path() / ("turncal-bad-" + std::to_string(::getpid()));
    {
      FILE* f = std::fopen(path.c_str(), "w");
      REQUIRE(f != nullptr);
      std::fputs("(1.000000) vcan0 123#00\n\n(1.000001) vcan0 124#01\n(1.000002) vcan0 12X#00\n",
                 f);
      std::fclose(f);
    }
    auto rd = LogReader::open(path.string());
    REQUIRE(rd.ok());
    auto a = rd->next();
    REQUIRE(a.ok());
    REQUIRE(a->has_value());
    auto b = rd->next();
    REQUIRE(b.ok());
    CHECK((*b)->frame.id == 0x124);
    auto c = rd->next();
    REQUIRE_FALSE(c.ok());
    CHECK(c.error().where.line == 4);
    CHECK(c.error().where.file == path.string());
    CHECK(c.error().describe().find(":4:") != std::string::npos);
    std::filesystem::remove(path);
  }

  TEST_CASE("a last line without a newline is read") {
    int fds[2];
    REQUIRE(::pipe(fds) == 0);
    const std::string text = "(1.000000) vcan0 123#00\n(2.000000) vcan0 124#01";
    REQUIRE(::write(fds[1], text.data(), text.size()) == static_cast<ssize_t>(text.size()));
    ::close(fds[1]);
    auto rd = LogReader::from_fd(fds[0], "pipe");
    auto a = rd.next();
    auto b = rd.next();
    auto c = rd.next();
    REQUIRE(b.ok());
    CHECK((*b)->frame.id == 0x124);
    REQUIRE(c.ok());
    CHECK_FALSE(c->has_value());
    ::close(fds[0]);
  }
}

#include "turncal/run/read_ahead.hpp"

TEST_SUITE("a log read ahead on a thread of its own") {
  // a log of `n` records, a blank line every 1000th line, and (bad_at > 0)
  // the line bad_at malformed; its path
  std::filesystem::path write_log(const char* name, int n, int bad_at) {
    const auto path = std::filesystem::temp_directory_path() /
                      (std::string("turncal-") + name + "-" + std::to_string(::getpid()));
    FILE* f = std::fopen(path.c_str(), "w");
    REQUIRE(f != nullptr);
    for (int line = 1, i = 0; i < n; ++line) {
      if (line == bad_at) {
        std::fputs("(1.000000) vcan0 12X#00\n", f);
      } else if (line % 1000 == 0) {
        std::fputs("\n", f);
      } else {
        std::fprintf(f, "(%d.%06d) vcan0 %03X#%02X\n", 1000 + i / 1000, i % 1000 * 1000,
                     0x100 + i % 7, i % 256);
        ++i;
      }
    }
    REQUIRE(std::fclose(f) == 0);
    return path;
  }

  // what each reader gives, record by record: time, id, first byte, line;
  // then how it ends (the error's text, or "end") and its last line
  std::string trace_line(const LogRecord& rec, std::uint64_t line) {
    return std::to_string(rec.time_ns) + " " + std::to_string(rec.frame.id) + " " +
           std::to_string(rec.frame.data[0]) + " @" + std::to_string(line);
  }
  std::vector<std::string> trace(LogReader & rd) {
    std::vector<std::string> out;
    LogRecord rec;
    for (;;) {
      auto got = rd.next(rec);
      if (!got) {
        out.push_back(got.error().describe() + " @" + std::to_string(rd.line_number()));
        return out;
      }
      if (!*got) {
        out.push_back("end @" + std::to_string(rd.line_number()));
        return out;
      }
      out.push_back(trace_line(rec, rd.line_number()));
    }
  }
  std::vector<std::string> trace(turncal::run::ReadAheadLogReader & rd) {
    std::vector<std::string> out;
    for (;;) {
      auto got = rd.next();
      if (!got) {
        out.push_back(got.error().describe() + " @" + std::to_string(rd.line_number()));
        return out;
      }
      if (*got == nullptr) {
        out.push_back("end @" + std::to_string(rd.line_number()));
        return out;
      }
      out.push_back(trace_line(**got, rd.line_number()));
    }
  }

  // the log at `path` traced by the plain reader and by the read-ahead one
  // (then given to `after`, if any)
  struct Traces {
    std::vector<std::string> plain, ahead;
  };
  Traces traces(const std::filesystem::path& path,
                const std::function<void(turncal::run::ReadAheadLogReader&)>& after = {}) {
    auto plain = LogReader::open(path.string());
    auto file = LogReader::open(path.string());
    REQUIRE(plain.ok());
    REQUIRE(file.ok());
    Traces t;
    t.plain = trace(*plain);
    turncal::run::ReadAheadLogReader ahead(std::move(*file));
    t.ahead = trace(ahead);
    if (after) after(ahead);
    return t;
  }

  TEST_CASE("it gives what the reader gives: every record, the line numbers, the end") {
    // more than the batches it parses ahead, and not a whole number of them
    const auto path = write_log("ahead", 4096 * 7 + 123, 0);
    const Traces t = traces(path);  // (no structured binding: clang 14's CHECK)
    const std::vector<std::string>& want = t.plain;
    REQUIRE(want.size() == 4096 * 7 + 123 + 1);
    CHECK(want.back() == "end @" + std::to_string(4096 * 7 + 123 + (4096 * 7 + 123) / 999));
    CHECK(t.ahead == want);
    std::filesystem::remove(path);
  }

  TEST_CASE("a log of whole batches, and an error at a batch's first line, read alike") {
    // 4096 records a batch: three whole ones (the last batch then empty),
    // and the line after the first batch's last record malformed
    struct Log {
      const char* name;
      int records, bad_at;
    };
    for (const Log& log :
         {Log{"ahead-whole", 4096 * 3, 0}, Log{"ahead-edge", 9000, 4096 + 4 + 1}}) {
      CAPTURE(log.name);  // (clang 14 cannot capture a structured binding)
      const int records = log.records, bad_at = log.bad_at;
      const auto path = write_log(log.name, records, bad_at);
      const Traces t = traces(path);
      const std::vector<std::string>& want = t.plain;
      CHECK(t.ahead == want);
      CHECK(want.size() == (bad_at > 0 ? 4097U : 4096U * 3 + 1));
      std::filesystem::remove(path);
    }
  }

  TEST_CASE("its error is the reader's, at the same record and line") {
    const auto path = write_log("ahead-bad", 20000, 9001);
    // where the plain reader would go on to the next line, this one ends
    std::optional<turncal::Result<const LogRecord*>> again;
    const Traces t =
        traces(path, [&](turncal::run::ReadAheadLogReader& ahead) { again.emplace(ahead.next()); });
    const std::vector<std::string>& want = t.plain;
    REQUIRE(want.size() == 9001 - 9001 / 1000);  // the records before it, and it
    CHECK(want.back().find(":9001:") != std::string::npos);
    CHECK(want.back().find("@9001") != std::string::npos);
    CHECK(t.ahead == want);
    REQUIRE(again.has_value());
    REQUIRE_FALSE(again->ok());
    CHECK(again->error().describe() == want.back().substr(0, want.back().rfind(" @")));
    std::filesystem::remove(path);
  }

  TEST_CASE("left early, it stops its thread") {
    const auto path = write_log("ahead-early", 4096 * 20, 0);
    auto file = LogReader::open(path.string());
    REQUIRE(file.ok());
    {
      turncal::run::ReadAheadLogReader ahead(std::move(*file));
      for (int i = 0; i < 10; ++i) {
        auto got = ahead.next();
        REQUIRE(got.ok());
        REQUIRE(*got != nullptr);
      }
      CHECK(ahead.line_number() == 10);
    }  // joins here: a thread left waiting would hang the test
    std::filesystem::remove(path);
  }
}
