#include <doctest/doctest.h>

#include <bit>
#include <cmath>
#include <iomanip>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "turncal/build_paths.hpp"
#include "turncal/can/dbc.hpp"

using namespace turncal::can;

namespace {

Signal make_signal(std::uint32_t start, std::uint32_t len, ByteOrder order,
                   bool is_signed = false) {
  Signal s;
  s.name = "S";
  s.start_bit = start;
  s.length = len;
  s.order = order;
  s.is_signed = is_signed;
  REQUIRE(s.finalize());
  return s;
}

const char* kSmall = R"(VERSION "1"

NS_ :
	NS_DESC_
	CM_
	BA_DEF_

BS_:

BU_: A B

BO_ 100 Engine: 8 A
 SG_ Speed : 0|16@1+ (0.1,0) [0|6553.5] "km/h" B
 SG_ Temp : 23|8@0- (1,-40) [-40|215] "degC" B,A
 SG_ Flag : 63|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 2147484000 Ext: 8 B
 SG_ F32 : 0|32@1- (1,0) [0|0] "" A
 SG_ Mux M : 32|8@1+ (1,0) [0|255] "" A
 SG_ Low m0 : 40|16@1+ (1,0) [0|65535] "" A
 SG_ High m1 : 40|24@1+ (2,1) [0|0] "" A

BO_ 200 Wide: 64 A
 SG_ D64 : 0|64@1- (1,0) [0|0] "" B
 SG_ Tail : 504|8@1+ (1,0) [0|255] "" B

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 10000;
BA_ "GenMsgCycleTime" BO_ 100 10;
CM_ "database comment";
CM_ BO_ 100 "engine data";
CM_ SG_ 100 Speed "vehicle
speed";
VAL_ 100 Flag 0 "off" 1 "on" ;
SIG_VALTYPE_ 2147484000 F32 : 1;
SIG_VALTYPE_ 200 D64 : 2;
)";

Database parsed(const std::string& text) {
  auto r = parse_dbc(text, "vendor.dbc");
  REQUIRE_MESSAGE(r.ok(), (r.ok() ? "" : r.error().describe()));
  for (const Diagnostic& w : r->warnings) {
    CHECK(w.where.file == "vendor.dbc");
    CHECK(w.where.line > 0);
  }
  return std::move(r).value();
}

/// The lines of the warnings (not the notes), in order.
std::vector<std::uint32_t> warning_lines(const Database& db) {
  std::vector<std::uint32_t> out;
  for (const Diagnostic& w : db.warnings)
    if (w.severity == Diagnostic::Severity::Warning) out.push_back(w.where.line);
  return out;
}

/// True when a warning at `line` says `text`.
bool warned(const Database& db, std::uint32_t line, const std::string& text) {
  for (const Diagnostic& w : db.warnings)
    if (w.where.line == line && w.text.find(text) != std::string::npos) return true;
  return false;
}

/// The signals a frame carries, by display name: what decode gives, NaN
/// (not carried) left out.
std::map<std::string, double> decoded(const Database& db, std::uint32_t id, bool extended,
                                      std::vector<std::uint8_t> bytes) {
  Frame f;
  f.id = id;
  f.extended = extended;
  f.len = static_cast<std::uint8_t>(bytes.size());
  std::copy(bytes.begin(), bytes.end(), f.data.begin());
  FrameCodec codec(db);
  const Message* m = codec.message_for(f);
  REQUIRE(m != nullptr);
  std::vector<double> out(m->signals.size());
  REQUIRE(codec.decode(f, out) == DecodeStatus::Ok);
  std::map<std::string, double> values;
  for (std::size_t i = 0; i < out.size(); ++i)
    if (!std::isnan(out[i])) values[m->signals[i].display_name()] = out[i];
  return values;
}

using Values = std::map<std::string, double>;

}  // namespace

TEST_SUITE("dbc") {
  TEST_CASE("Intel and Motorola layouts match hand-worked vectors") {
    const std::uint8_t data[8] = {0x12, 0x34, 0x56, 0x78, 0x9A, 0xBC, 0xDE, 0xF0};
    SUBCASE("Intel byte") {
      CHECK(extract_raw(make_signal(0, 8, ByteOrder::LittleEndian), data) == 0x12);
    }
    SUBCASE("Intel 16 across bytes") {
      CHECK(extract_raw(make_signal(0, 16, ByteOrder::LittleEndian), data) == 0x3412);
    }
    SUBCASE("Intel unaligned nibble pair") {
      CHECK(extract_raw(make_signal(4, 8, ByteOrder::LittleEndian), data) == 0x41);
    }
    SUBCASE("Intel 64") {
      CHECK(extract_raw(make_signal(0, 64, ByteOrder::LittleEndian), data) ==
            0xF0DEBC9A78563412ull);
    }
    SUBCASE("Motorola byte") {
      CHECK(extract_raw(make_signal(7, 8, ByteOrder::BigEndian), data) == 0x12);
    }
    SUBCASE("Motorola 16") {
      CHECK(extract_raw(make_signal(7, 16, ByteOrder::BigEndian), data) == 0x1234);
    }
    SUBCASE("Motorola low nibble") {
      CHECK(extract_raw(make_signal(3, 4, ByteOrder::BigEndian), data) == 0x2);
    }
    SUBCASE("Motorola across bytes") {
      // bits 3..0 of byte 0 (0x2), then bits 7..4 of byte 1 (0x3)
      CHECK(extract_raw(make_signal(3, 8, ByteOrder::BigEndian), data) == 0x23);
    }
    SUBCASE("Motorola 64") {
      CHECK(extract_raw(make_signal(7, 64, ByteOrder::BigEndian), data) == 0x123456789ABCDEF0ull);
    }
    SUBCASE("sign extension") {
      const Signal s = make_signal(4, 4, ByteOrder::LittleEndian, true);  // high nibble of 0x12: 1
      CHECK(raw_to_integer(s, extract_raw(s, data)) == 1);
      const Signal t = make_signal(56, 8, ByteOrder::LittleEndian, true);  // 0xF0 = -16
      CHECK(raw_to_integer(t, extract_raw(t, data)) == -16);
    }
  }

  TEST_CASE("a small database parses with every section") {
    auto r = parse_dbc(kSmall, "small.dbc");
    REQUIRE_MESSAGE(r.ok(), (r.ok() ? "" : r.error().describe()));
    const Database& db = *r;
    CHECK(db.version == "1");
    CHECK(db.nodes == std::vector<std::string>{"A", "B"});
    REQUIRE(db.messages.size() == 3);
    const Message* eng = db.find("Engine");
    REQUIRE(eng != nullptr);
    CHECK(eng->id == 100);
    CHECK_FALSE(eng->extended);
    CHECK(eng->comment == "engine data");
    const Signal* temp = eng->find_signal("Temp");
    REQUIRE(temp != nullptr);
    CHECK(temp->order == ByteOrder::BigEndian);
    CHECK(temp->is_signed);
    CHECK(temp->offset == -40);
    CHECK(temp->unit == "degC");
    CHECK(temp->receivers == std::vector<std::string>{"B", "A"});
    CHECK(eng->find_signal("Speed")->comment == "vehicle\nspeed");
    CHECK(eng->find_signal("Flag")->values.at(1) == "on");
    const Message* ext = db.find(352, true);
    REQUIRE(ext != nullptr);
    CHECK(ext->name == "Ext");
    CHECK(ext->find_signal("F32")->type == ValueType::Float32);
    CHECK(ext->multiplexor()->name == "Mux");
    CHECK(ext->find_signal("High")->mux == MuxRole::Multiplexed);
    CHECK(ext->find_signal("High")->mux_value == 1);
    const Message* wide = db.find("Wide");
    REQUIRE(wide != nullptr);
    CHECK(wide->fd);
    CHECK(wide->find_signal("D64")->type == ValueType::Float64);
  }

  TEST_CASE("frames decode and encode through the codec") {
    auto db = parse_dbc(kSmall, "small.dbc");
    REQUIRE(db.ok());
    FrameCodec codec(*db);
    const Message* ext = db->find("Ext");
    SUBCASE("multiplexed signals follow the multiplexor") {
      const std::vector<double> in = {-1.5, 1, 7, 201};  // F32, Mux, Low, High
      Frame f = FrameCodec::encode(*ext, in);
      CHECK(f.extended);
      std::vector<double> out(4);
      REQUIRE(codec.decode(f, out) == DecodeStatus::Ok);
      CHECK(out[0] == -1.5);
      CHECK(out[1] == 1);
      CHECK(std::isnan(out[2]));
      CHECK(out[3] == 201);
    }
    SUBCASE("a frame of the wrong length is refused, counted and skipped") {
      Frame good = FrameCodec::encode(*db->find("Engine"), std::vector<double>{1, 2, 0});
      Frame bad = good;
      bad.len = 7;
      std::vector<double> out(3);
      DecodeCounts counts;
      for (const Frame* f : {&good, &bad, &good}) counts.add(codec.decode(*f, out));
      CHECK(counts.ok == 2);
      CHECK(counts.length_mismatch == 1);
      CHECK(counts.malformed() == 1);
      CHECK(out[0] == doctest::Approx(1));  // the good frame after the bad one decoded
    }
    SUBCASE("unknown IDs and error frames are not data") {
      Frame f;
      f.id = 0x7FF;
      f.len = 8;
      std::vector<double> out(3);
      CHECK(codec.decode(f, out) == DecodeStatus::UnknownId);
      f.error = true;
      CHECK(codec.decode(f, out) == DecodeStatus::NotData);
    }
    SUBCASE("a value that does not fit its signal is refused, never saturated") {
      const Signal* speed = db->find("Engine")->find_signal("Speed");  // u16, 0.1, [0|6553.5]
      CHECK(*physical_to_raw(*speed, 12.34) == 123);
      CHECK(*physical_to_raw(*speed, 6553.5) == 0xFFFF);
      CHECK(*physical_to_raw(*speed, 0) == 0);
      CHECK(*physical_to_raw(*speed, -0.04) == 0);  // within half a step: rounds to the end
      for (double v : {1e9, 6553.6, -5.0, -0.06, std::nan(""), HUGE_VAL}) {
        CAPTURE(v);
        CHECK_FALSE(fits(*speed, v));
        const auto r = physical_to_raw(*speed, v);
        REQUIRE_FALSE(r.ok());
        CHECK(r.error().message.find("does not fit signal Speed (0.0 to 6553.5 km/h)") !=
              std::string::npos);
      }
      // the frame codec names the message too; the unchecked path clamps
      const std::vector<double> values = {1e9, 2, 0};
      const auto f = FrameCodec::encode_checked(*db->find("Engine"), values);
      REQUIRE_FALSE(f.ok());
      CHECK(f.error().message == "1000000000 km/h does not fit Engine.Speed (0.0 to 6553.5 km/h)");
      const std::vector<double> good = {12.3, 2, 0};
      REQUIRE(FrameCodec::encode_checked(*db->find("Engine"), good).ok());
      CHECK(extract_raw(*speed, FrameCodec::encode(*db->find("Engine"), values).payload()) ==
            0xFFFF);
    }
    SUBCASE("the DBC's [min|max] narrows the raw range; [0|0] gives none") {
      // s8 with offset -40 carries -168 to 87; the file says [-40|215]: -40 to 87
      const Signal* temp = db->find("Engine")->find_signal("Temp");
      CHECK(physical_range(*temp).lo == -40);
      CHECK(physical_range(*temp).hi == 87);
      CHECK(fits(*temp, -40));
      CHECK(fits(*temp, 87));
      CHECK_FALSE(fits(*temp, -41));
      CHECK_FALSE(fits(*temp, 88));
      const Signal* f32 = db->find("Ext")->find_signal("F32");
      CHECK(fits(*f32, -1.5));
      CHECK_FALSE(fits(*f32, 1e39));                            // beyond a float
      const Signal* low = db->find("Ext")->find_signal("Low");  // u16, [0|65535]
      CHECK(fits(*low, 65535));
      const Signal* high = db->find("Ext")->find_signal("High");  // u24, factor 2, offset 1, [0|0]
      CHECK(physical_range(*high).hi == 2.0 * 16777215 + 1);
      CHECK(fits(*high, 2.0 * 16777215 + 1));
      CHECK_FALSE(fits(*high, 2.0 * 16777216 + 1));
      Signal narrow = *low;
      narrow.minimum = 10;
      narrow.maximum = 20;
      CHECK(fits(narrow, 10));
      CHECK(fits(narrow, 20));
      CHECK_FALSE(fits(narrow, 21));
      CHECK_FALSE(fits(narrow, 9));
      CHECK(describe_range(narrow) == "10 to 20");
    }
  }

  TEST_CASE("the reference stand DBC parses") {
    auto r = load_dbc(std::string(turncal::build::source_dir) + "/config/reference-stand.dbc");
    REQUIRE_MESSAGE(r.ok(), (r.ok() ? "" : r.error().describe()));
    CHECK(r->messages.size() == 8);
    const Message* enc = r->find(0x201, false);
    REQUIRE(enc != nullptr);
    CHECK(enc->name == "TBL_Encoder");
    const Signal* angle = enc->find_signal("Angle");
    REQUIRE(angle != nullptr);
    CHECK(angle->factor * 4294967296.0 == 360.0);  // 2^-32 rev in degrees, exactly
    CHECK(r->find("HOST_Heartbeat")->size == 2);
    CHECK(r->find("INS_Status")->find_signal("Mode")->values.at(2) == "navigating");
  }

  TEST_CASE("malformed files give errors with file and line") {
    struct Case {
      const char* text;
      std::uint32_t line;
    };
    // (a signal that does not fit, or cannot be decoded, an SG_ line that
    // cannot be read, an ID above 0x7FF without the extended flag, a
    // message of no CAN size or an ID defined twice, an unknown keyword and
    // an SG_ line outside a message are read with a warning now: see the
    // test cases below)
    const Case cases[] = {
        {"BO_ 1 M: 8 A\n SG_ S : 0|8@1+ (1,0) [0|1]\n SG_ T : 8|8@1+ (1,0) [0|1] \"\" B\n", 3},
        {"BO_ 1 M: 8 A\n SG_ S : 0|8@1+ (1,0) [0|1] \"unterminated\n", 2},
        {"BO_ 536870912 M: 8 A\n", 1},   // above 0x1FFFFFFF: not a CAN ID with or without the flag
        {"BO_ 2684354560 M: 8 A\n", 1},  // the flag and 0x20000000
        {"BO_ 1 M: 8 A\n SG_ S M : 0|8@1+ (1,0) [0|1] \"\" B\n\nSG_MUL_VAL_ 1 S S 1+2;\n", 4},
    };
    for (const Case& c : cases) {
      CAPTURE(c.text);
      auto r = parse_dbc(c.text, "bad.dbc");
      REQUIRE_FALSE(r.ok());
      CHECK(r.error().where.file == "bad.dbc");
      CHECK(r.error().where.line == c.line);
    }
  }

  TEST_CASE("unknown sections are skipped and stale references ignored") {
    const char* text =
        "BO_ 1 M: 8 A\n SG_ S : 0|8@1+ (1,0) [0|1] \"\" B\n"
        "BA_DEF_ SG_ \"X\" ENUM \"a\",\"b\";\nBA_DEF_DEF_ \"X\" \"a\";\n"
        "EV_ E: 0 [0|1] \"\" 0 1 DUMMY_NODE_VECTOR0 A;\nSG_MUL_VAL_ 1 S S 0-0;\n"
        "VAL_TABLE_ T 1 \"x\" 0 \"y\";\nVAL_ E 0 \"a\";\nCM_ SG_ 99 Nope \"stale\";\n"
        "BO_TX_BU_ 1 : A,B;\n";
    auto r = parse_dbc(text, "ok.dbc");
    REQUIRE_MESSAGE(r.ok(), (r.ok() ? "" : r.error().describe()));
    CHECK(r->messages.size() == 1);
    // the stale ones are named: SG_MUL_VAL_ for a signal that is not
    // multiplexed (line 6), a comment for a message the file lacks (line 9)
    CHECK(warning_lines(*r) == std::vector<std::uint32_t>{6, 9});
  }

  TEST_CASE("property: random layouts encode and decode as inverses, through DBC text") {
    std::mt19937_64 rng(0x7c0ffee);
    int signals_checked = 0, floats = 0, negative = 0, round_trips = 0;
    // raw to physical and back gives the raw value: an integer signal whose
    // physical value is exact in a double (52 bits unscaled, 48 scaled
    // exactly); scaled inexactly, the raw value within 1
    const auto exact = [](const Signal& s) {
      if (s.type != ValueType::Integer) return false;
      if (s.factor == 1 && s.offset == 0) return s.length <= 52;
      return s.length <= 48 &&
             (s.factor == 1 || s.factor == -0.5 || s.factor == 0.25 || s.factor == 3) &&
             (s.offset == 0 || s.offset == -40 || s.offset == 1234.5);
    };
    const auto near = [](const Signal& s) {
      return s.type == ValueType::Integer && s.length <= 32 && !(s.factor == 1 && s.offset == 0);
    };
    for (int trial = 0; trial < 400; ++trial) {
      const bool fd = trial % 4 == 0;
      const std::uint32_t size = fd ? 64 : 8;
      std::vector<bool> used(size * 8, false);
      std::ostringstream dbc;
      dbc << "BO_ " << (fd ? 0x80000000u + 0x1234567u : 0x123u) << " M: " << size << " A\n";
      std::vector<Signal> layout;
      std::ostringstream valtypes;  // the 32- and 64-bit signals made IEEE floats, some of them
      // scalings as DBC files have them, written to be read back exactly;
      // two thirds of them exact in binary (what they give turns back into
      // the same raw value), the offsets but the last too
      constexpr double kExactFactors[] = {1, -0.5, 0.25, 3};
      constexpr double kFactors[] = {0.01, 1e-6, 8.381903171539306640625e-08};
      constexpr double kOffsets[] = {0, -40, 1234.5, -0.001};
      for (int attempt = 0; attempt < 40 && layout.size() < 12; ++attempt) {
        Signal s;
        s.name = "S" + std::to_string(layout.size());
        s.length = static_cast<std::uint32_t>(1 + rng() % 64);
        if (rng() % 6 == 0) s.length = rng() % 2 == 0 ? 32 : 64;  // often float-sized
        s.order = (rng() % 2) ? ByteOrder::LittleEndian : ByteOrder::BigEndian;
        s.start_bit = static_cast<std::uint32_t>(rng() % (size * 8));
        s.is_signed = (rng() % 2) != 0;
        if (!s.finalize() || s.end_byte() > size) continue;
        // occupancy: insert all ones into an empty payload and look
        std::vector<std::uint8_t> probe(size, 0);
        insert_raw(s, probe, ~0ull);
        bool clash = false;
        int bits = 0;
        for (std::uint32_t b = 0; b < size * 8; ++b) {
          if ((static_cast<unsigned>(probe[b / 8]) >> (b % 8)) & 1u) {
            ++bits;
            clash = clash || used[b];
          }
        }
        REQUIRE(bits == static_cast<int>(s.length));
        if (clash) continue;
        for (std::uint32_t b = 0; b < size * 8; ++b)
          if ((static_cast<unsigned>(probe[b / 8]) >> (b % 8)) & 1u) used[b] = true;
        s.factor = rng() % 3 != 0 ? kExactFactors[rng() % std::size(kExactFactors)]
                                  : kFactors[rng() % std::size(kFactors)];
        s.offset = kOffsets[rng() % std::size(kOffsets)];
        dbc << std::setprecision(17) << " SG_ " << s.name << " : " << s.start_bit << "|" << s.length
            << "@" << (s.order == ByteOrder::LittleEndian ? 1 : 0) << (s.is_signed ? "-" : "+")
            << " (" << s.factor << "," << s.offset << ") [0|0] \"\" B\n";
        if ((s.length == 32 || s.length == 64) && rng() % 2 == 0)
          valtypes << "SIG_VALTYPE_ " << (fd ? 0x80000000u + 0x1234567u : 0x123u) << " " << s.name
                   << " : " << (s.length == 32 ? 1 : 2) << ";\n";
        layout.push_back(s);
      }
      auto db = parse_dbc(dbc.str() + valtypes.str(), "random.dbc");
      REQUIRE_MESSAGE(db.ok(), (db.ok() ? "" : db.error().describe()));
      const Message& m = db->messages.at(0);
      for (std::size_t i = 0; i < layout.size(); ++i) {
        CHECK(m.signals[i].factor == layout[i].factor);
        CHECK(m.signals[i].offset == layout[i].offset);
        floats += m.signals[i].type != ValueType::Integer;
        negative += m.signals[i].is_signed && m.signals[i].type == ValueType::Integer;
      }
      CHECK(m.extended == fd);
      REQUIRE(m.signals.size() == layout.size());
      std::vector<std::uint64_t> raws;
      std::vector<std::uint8_t> payload(size);
      for (auto& b : payload) b = static_cast<std::uint8_t>(rng());
      for (std::size_t i = 0; i < layout.size(); ++i) {
        CHECK(m.signals[i].first_byte == layout[i].first_byte);
        CHECK(m.signals[i].span == layout[i].span);
        CHECK(m.signals[i].shift == layout[i].shift);
        const std::uint64_t mask = layout[i].length == 64 ? ~0ull : (1ull << layout[i].length) - 1;
        raws.push_back(rng() & mask);
        insert_raw(m.signals[i], payload, raws.back());
      }
      for (std::size_t i = 0; i < layout.size(); ++i) {
        const Signal& s = m.signals[i];
        CHECK(extract_raw(s, payload) == raws[i]);
        if (exact(s)) {
          ++round_trips;
          CHECK(*physical_to_raw(s, raw_to_physical(s, raws[i])) == raws[i]);
        } else if (near(s)) {
          const auto back = physical_to_raw(s, raw_to_physical(s, raws[i]));
          REQUIRE(back.ok());
          const auto b = static_cast<std::int64_t>(raw_to_integer(s, *back)),
                     w = static_cast<std::int64_t>(raw_to_integer(s, raws[i]));
          CHECK(std::abs(b - w) <= 1);
        }
        ++signals_checked;
      }
      // the whole-frame codec agrees with the per-signal one
      Frame f;
      f.id = m.id;
      f.extended = m.extended;
      f.fd = m.fd;
      f.len = static_cast<std::uint8_t>(size);
      // bytes past the payload hold junk: the codec reads 8 bytes at a
      // time where they fit in the frame's data, and must drop them
      for (auto& b : f.data) b = static_cast<std::uint8_t>(rng());
      std::copy(payload.begin(), payload.end(), f.data.begin());
      FrameCodec codec(*db);
      std::vector<double> phys(m.signals.size());
      REQUIRE(codec.decode(f, phys) == DecodeStatus::Ok);
      for (std::size_t i = 0; i < m.signals.size(); ++i) {
        CAPTURE(i);
        CHECK(std::bit_cast<std::uint64_t>(phys[i]) ==
              std::bit_cast<std::uint64_t>(raw_to_physical(m.signals[i], raws[i])));
      }
      const Frame g = FrameCodec::encode(m, phys);
      for (std::size_t i = 0; i < m.signals.size(); ++i)
        if (exact(m.signals[i])) CHECK(extract_raw(m.signals[i], g.payload()) == raws[i]);
    }
    CHECK(signals_checked > 1500);
    CHECK(floats > 50);        // IEEE float and double signals among them
    CHECK(negative > 500);     // and signed integers
    CHECK(round_trips > 600);  // and a good part of them back and forth
  }

  TEST_CASE("the codec knows its widest message: 70 one-bit signals of a 64-byte FD frame") {
    std::string text =
        "BO_ 1 A: 1 X\n SG_ a : 0|8@1+ (1,0) [0|0] \"\" X\n"
        "BO_ 2 Wide: 64 X\n";
    for (int k = 0; k < 70; ++k)
      text += " SG_ s" + std::to_string(k) + " : " + std::to_string(k * 7) +
              "|1@1+ (1,0) [0|0] \"\" X\n";
    auto db = parse_dbc(text, "wide.dbc");
    REQUIRE(db.ok());
    REQUIRE(db->messages.size() == 2);
    const FrameCodec codec(*db);
    CHECK(codec.max_signals() == 70);
    // and every one of them decodes into an `out` that wide
    Frame f;
    f.id = 2;
    f.fd = true;
    f.len = 64;
    f.data[(69 * 7) / 8] = static_cast<std::uint8_t>(1u << ((69 * 7) % 8));
    std::vector<double> out(codec.max_signals(), -1);
    REQUIRE(codec.decode(f, out) == DecodeStatus::Ok);
    CHECK(out[69] == 1);
    CHECK(out[68] == 0);
  }

  TEST_CASE("float signals round trip") {
    auto db = parse_dbc(kSmall, "small.dbc");
    REQUIRE(db.ok());
    const Signal* d64 = db->find("Wide")->find_signal("D64");
    std::vector<std::uint8_t> payload(64, 0);
    for (double v : {0.0, -1.0, 3.141592653589793, 1e300, -2.5e-300}) {
      insert_raw(*d64, payload, *physical_to_raw(*d64, v));
      CHECK(raw_to_physical(*d64, extract_raw(*d64, payload)) == v);
    }
  }
  TEST_CASE("an ID above 0x7FF without the extended flag is read as extended, with a warning") {
    const Database db = parsed(
        "VERSION \"\"\n"
        "BO_ 4000 Wide_Id: 8 A\n"  // 2: 0xFA0, no bit 31
        " SG_ Speed : 0|16@1+ (0.5,0) [0|0] \"\" B\n"
        "BO_ 2147487649 Flagged: 2 A\n"  // 4: 0xFA1 with bit 31: no warning
        " SG_ X : 0|8@1+ (1,0) [0|0] \"\" B\n"
        "BO_ 2047 Std: 1 A\n"  // 6: 0x7FF: standard
        " SG_ Y : 0|8@1+ (1,0) [0|0] \"\" B\n"
        "CM_ BO_ 2147487648 \"written with the flag\";\n"  // 8: the same message
        "VAL_ 4000 Speed 2 \"one\";\n");
    CHECK(warning_lines(db) == std::vector<std::uint32_t>{2});
    CHECK(warned(db, 2, "0xFA0 is above 0x7FF without the extended flag"));
    const Message* m = db.find(0xFA0, true);
    REQUIRE(m != nullptr);
    CHECK(m->name == "Wide_Id");
    CHECK(db.find(0xFA0, false) == nullptr);
    CHECK(m->comment == "written with the flag");
    CHECK(m->find_signal("Speed")->values.at(2) == "one");
    CHECK(db.find(0xFA1, true)->name == "Flagged");
    CHECK_FALSE(db.find("Std")->extended);
    CHECK(decoded(db, 0xFA0, true, {0x10, 0x27, 0, 0, 0, 0, 0, 0}) == Values{{"Speed", 5000}});
    // the same ID as a standard frame is no frame of the file
    Frame f;
    f.id = 0xFA0 & 0x7FF;
    f.len = 8;
    std::vector<double> out(1);
    CHECK(FrameCodec(db).decode(f, out) == DecodeStatus::UnknownId);
  }

  TEST_CASE("extended multiplexing: SG_MUL_VAL_ ranges and m1M chains select what decode gives") {
    const Database db = parsed(
        "BO_ 300 Mux: 8 A\n"
        " SG_ Top M : 0|8@1+ (1,0) [0|0] \"\" B\n"     // 2
        " SG_ Sub m1M : 8|8@1+ (1,0) [0|0] \"\" B\n"   // 3: multiplexed and multiplexor
        " SG_ A m2 : 16|16@1+ (0.5,0) [0|0] \"\" B\n"  // 4: Sub in 2-3
        " SG_ B m5 : 16|16@1- (1,0) [0|0] \"\" B\n"    // 5: Sub 5, 10-12
        " SG_ C m0 : 8|16@1+ (1,10) [0|0] \"\" B\n"    // 6: Top 0 or 7-9
        " SG_ Always : 56|8@1+ (1,0) [0|0] \"\" B\n"   // 7
        "BO_ 301 Two: 8 A\n"                           // 8: two multiplexors, no SG_MUL_VAL_
        " SG_ P M : 0|8@1+ (1,0) [0|0] \"\" B\n"
        " SG_ Q M : 8|8@1+ (1,0) [0|0] \"\" B\n"
        " SG_ R m1 : 16|8@1+ (1,0) [0|0] \"\" B\n"  // 11: whose?
        " SG_ S : 24|8@1+ (1,0) [0|0] \"\" B\n"
        "SG_MUL_VAL_ 300 Sub Top 1-1;\n"
        "SG_MUL_VAL_ 300 A Sub 2-3;\n"
        "SG_MUL_VAL_ 300 B Sub 5-5, 10-12;\n"
        "SG_MUL_VAL_ 300 C Top 0-0, 7 - 9;\n"
        "SG_MUL_VAL_ 300 Nope Top 1-1;\n");  // 17: no such signal
    CHECK(warning_lines(db) == std::vector<std::uint32_t>{11, 17});
    CHECK(warned(db, 11, "several multiplexors"));
    const Message* m = db.find("Mux");
    REQUIRE(m != nullptr);
    const Signal* sub = m->find_signal("Sub");
    CHECK(sub->is_multiplexor());
    CHECK(sub->mux == MuxRole::Multiplexed);
    CHECK(sub->selected_by == std::vector<MuxRange>{{1, 1}});
    CHECK(m->find_signal("B")->selected_by == std::vector<MuxRange>{{5, 5}, {10, 12}});
    CHECK(m->find_signal("C")->selected_by == std::vector<MuxRange>{{0, 0}, {7, 9}});
    // Top 1 selects Sub; Sub 2 and 3 select A, 5 and 10..12 B
    CHECK(decoded(db, 300, false, {1, 2, 0x10, 0x00, 0, 0, 0, 42}) ==
          Values{{"Top", 1}, {"Sub", 2}, {"A", 8}, {"Always", 42}});
    CHECK(decoded(db, 300, false, {1, 3, 0x10, 0x00, 0, 0, 0, 42}) ==
          Values{{"Top", 1}, {"Sub", 3}, {"A", 8}, {"Always", 42}});
    CHECK(decoded(db, 300, false, {1, 11, 0xFE, 0xFF, 0, 0, 0, 42}) ==
          Values{{"Top", 1}, {"Sub", 11}, {"B", -2}, {"Always", 42}});
    CHECK(decoded(db, 300, false, {1, 4, 0xFE, 0xFF, 0, 0, 0, 42}) ==
          Values{{"Top", 1}, {"Sub", 4}, {"Always", 42}});
    // Top 8 selects C, not Sub (whose value 2 would select A)
    CHECK(decoded(db, 300, false, {8, 2, 0, 0, 0, 0, 0, 42}) ==
          Values{{"Top", 8}, {"C", 10 + 2}, {"Always", 42}});
    CHECK(decoded(db, 300, false, {2, 2, 0, 0, 0, 0, 0, 42}) == Values{{"Top", 2}, {"Always", 42}});
    // two multiplexors and no SG_MUL_VAL_: R is left out, the rest decodes
    CHECK_FALSE(db.find("Two")->find_signal("R")->usable);
    CHECK(decoded(db, 301, false, {1, 1, 1, 7, 0, 0, 0, 0}) ==
          Values{{"P", 1}, {"Q", 1}, {"S", 7}});
    // encode follows the same chain: A is written only where Top and Sub select it
    std::vector<double> values = {1, 3, 8, -2, 12, 42};
    Frame f = FrameCodec::encode(*m, values);
    CHECK(f.data[2] == 0x10);
    values[1] = 4;  // Sub 4 selects neither A nor B
    f = FrameCodec::encode(*m, values);
    CHECK(f.data[2] == 0);
  }

  TEST_CASE("long names: the System*LongSymbol attributes name what the DBC cut to 32") {
    const Database db = parsed(
        "BU_: ECU_With_A_Long_Name_Cut_To_32_\n"
        "BO_ 100 Engine_Status_Message_Cut_To_32: 8 ECU_With_A_Long_Name_Cut_To_32_\n"
        " SG_ Engine_Coolant_Temperature_Cut : 0|8@1+ (1,-40) [0|0] \"\" B\n"
        " SG_ Short : 8|8@1+ (2,0) [0|0] \"\" B\n"
        "BA_DEF_ SG_ \"SystemSignalLongSymbol\" STRING ;\n"
        "BA_DEF_ BO_ \"SystemMessageLongSymbol\" STRING ;\n"
        "BA_DEF_ BU_ \"SystemNodeLongSymbol\" STRING ;\n"
        "BA_DEF_ EV_ \"SystemEnvVarLongSymbol\" STRING ;\n"
        "BA_DEF_DEF_ \"SystemSignalLongSymbol\" \"\";\n"
        "BA_ \"SystemMessageLongSymbol\" BO_ 100 \"Engine_Status_Message_Cut_To_32_Characters\";\n"
        "BA_ \"SystemSignalLongSymbol\" SG_ 100 Engine_Coolant_Temperature_Cut "
        "\"Engine_Coolant_Temperature_Celsius\";\n"
        "BA_ \"SystemNodeLongSymbol\" BU_ ECU_With_A_Long_Name_Cut_To_32_ "
        "\"ECU_With_A_Long_Name_Cut_To_32_Characters\";\n"
        "BA_ \"SystemEnvVarLongSymbol\" EV_ Env_Short \"Env_Long_Name\";\n"  // 13
        "BA_ \"SystemSignalLongSymbol\" SG_ 100 Gone \"Gone_Long\";\n");     // 14
    CHECK(warning_lines(db) == std::vector<std::uint32_t>{14});
    const Message* by_short = db.find("Engine_Status_Message_Cut_To_32");
    const Message* by_long = db.find("Engine_Status_Message_Cut_To_32_Characters");
    REQUIRE(by_short != nullptr);
    CHECK(by_short == by_long);
    CHECK(by_short->display_name() == "Engine_Status_Message_Cut_To_32_Characters");
    CHECK(by_short->name == "Engine_Status_Message_Cut_To_32");
    const Signal* s = by_short->find_signal("Engine_Coolant_Temperature_Celsius");
    REQUIRE(s != nullptr);
    CHECK(s == by_short->find_signal("Engine_Coolant_Temperature_Cut"));
    CHECK(s->name == "Engine_Coolant_Temperature_Cut");
    CHECK(by_short->find_signal("Short")->display_name() == "Short");
    CHECK(db.node_long_names.at("ECU_With_A_Long_Name_Cut_To_32_") ==
          "ECU_With_A_Long_Name_Cut_To_32_Characters");
    CHECK(db.warnings.front().where.line == 13);  // a note: environment variables are not read
    CHECK(db.warnings.front().severity == Diagnostic::Severity::Note);
    CHECK(decoded(db, 100, false, {60, 21, 0, 0, 0, 0, 0, 0}) ==
          Values{{"Engine_Coolant_Temperature_Celsius", 20}, {"Short", 42}});
  }

  TEST_CASE("VECTOR__INDEPENDENT_SIG_MSG is skipped with a note, never a CAN message") {
    const Database db = parsed(
        "BO_ 3221225472 VECTOR__INDEPENDENT_SIG_MSG: 0 Vector__XXX\n"
        " SG_ Unassigned : 0|16@1+ (1,0) [0|0] \"\" Vector__XXX\n"
        "BO_ 5 Real: 1 A\n"
        " SG_ X : 0|8@1+ (1,0) [0|0] \"\" B\n"
        "CM_ SG_ 3221225472 Unassigned \"no message\";\n"
        "VAL_ 3221225472 Unassigned 0 \"zero\";\n");
    CHECK(warning_lines(db).empty());
    REQUIRE(db.warnings.size() == 1);
    CHECK(db.warnings[0].severity == Diagnostic::Severity::Note);
    CHECK(db.warnings[0].where.line == 1);
    REQUIRE(db.messages.size() == 1);
    CHECK(db.find("VECTOR__INDEPENDENT_SIG_MSG") == nullptr);
    CHECK(db.find(0, true) == nullptr);
    CHECK(decoded(db, 5, false, {9}) == Values{{"X", 9}});
  }

  TEST_CASE("a signal that cannot be decoded is kept unusable with a warning; the rest decodes") {
    const Database db = parsed(
        "BO_ 1 M: 8 A\n"
        " SG_ S : 0|8@1+ (1,0) [0|1] \"\" B\n"
        " SG_ T : 60|8@1+ (1,0) [0|1] \"\" B\n"        // 3: beyond 8 bytes
        " SG_ Long : 0|65@1+ (1,0) [0|1] \"\" B\n"     // 4: 65 bits
        " SG_ Flat : 8|8@1+ (0,0) [0|1] \"\" B\n"      // 5: factor 0
        " SG_ Lost m1 : 16|8@1+ (1,0) [0|1] \"\" B\n"  // 6: no multiplexor
        " SG_ F : 24|16@1+ (1,0) [0|1] \"\" B\n"       // 7: float of 16 bits
        " SG_ Moto : 35|8@0+ (1,0) [0|0] \"\" B\n"     // 8: Motorola from byte 4 into 5: fits
        " SG_ Tail : 63|1@1+ (1,0) [0|1] \"\" B\n"
        "SIG_VALTYPE_ 1 F : 1;\n");
    CHECK(warning_lines(db) == std::vector<std::uint32_t>{3, 4, 5, 6, 7});
    CHECK(warned(db, 3, "'M.T' left out: start 60, 8 bits does not fit the message's 8 bytes"));
    const Message* m = db.find("M");
    for (const char* n : {"T", "Long", "Flat", "Lost", "F"}) {
      CAPTURE(n);
      CHECK_FALSE(m->find_signal(n)->usable);
      CHECK_FALSE(m->find_signal(n)->problem.empty());
    }
    CHECK(m->find_signal("S")->usable);
    CHECK(decoded(db, 1, false, {0xAB, 0x0C, 7, 0, 0x0B, 0x00, 0, 0x80}) ==
          Values{{"S", 0xAB}, {"Moto", 0xB0}, {"Tail", 1}});
    // encode leaves them out too
    const std::vector<double> values = {1, 255, 1, 1, 1, 1, 0, 0};
    const Frame f = FrameCodec::encode(*m, values);
    CHECK(f.data[0] == 1);
    CHECK(f.data[7] == 0);
  }

  TEST_CASE("an SG_ line that cannot be read is skipped with a warning; its message keeps it") {
    const Database db = parsed(
        "BO_ 1 M: 8 A\n"
        " SG_ S : 0|8@2+ (1,0) [0|1] \"\" B\n"      // 2: byte order 2
        " SG_ T m1x : 8|8@1+ (1,0) [0|1] \"\" B\n"  // 3: bad multiplexer indicator
        " SG_ U : 16|8@1+ (1,0) [0|255] \"\" B\n"
        " SG_ U : 24|8@1+ (1,0) [0|255] \"\" B\n"  // 5: U again
        " SG_ V : 32|8@1+ (1,0) [0|255] \"\" B\n"
        "BO_ 2 N: 1 A\n"
        " SG_ W : 0|8@1+ (1,0) [0|255] \"\" B\n");
    CHECK(warning_lines(db) == std::vector<std::uint32_t>{2, 3, 5});
    CHECK(warned(db, 2,
                 "SG_ line of message 'M' not read, its signal left out: expected byte "
                 "order 0 or 1, found '2'"));
    CHECK(warned(db, 5, "signal 'U' defined twice in M"));
    const Message* m = db.find("M");
    REQUIRE(m->unread.size() == 3);
    CHECK(m->unread[0].where.line == 2);
    CHECK(m->unread[0].where.file == "vendor.dbc");
    CHECK(db.find("N")->unread.empty());
    CHECK(decoded(db, 1, false, {1, 2, 3, 4, 5, 6, 7, 8}) == Values{{"U", 3}, {"V", 5}});
    CHECK(decoded(db, 2, false, {9}) == Values{{"W", 9}});
  }

  TEST_CASE("a message of no CAN size, or an ID defined twice, is left out; the rest reads") {
    const Database db = parsed(
        "BO_ 1 M: 9 A\n"  // 1: no CAN or CAN FD length
        " SG_ S : 0|8@1+ (1,0) [0|1] \"\" B\n"
        "BO_ 2 N: 8 A\n"  // 3
        " SG_ T : 0|8@1+ (1,0) [0|255] \"\" B\n"
        "BO_ 2 O: 8 A\n"  // 5: N's ID again
        " SG_ U : 0|8@1+ (1,0) [0|255] \"\" B\n"
        "BO_ 3 P: 1 A\n"  // 7
        " SG_ W : 0|8@1+ (1,0) [0|255] \"\" B\n");
    CHECK(warning_lines(db) == std::vector<std::uint32_t>{1, 5});
    CHECK(warned(db, 1, "message 'M' left out with its signals: message size 9 is not a CAN"));
    CHECK(warned(db, 5, "message 'O' left out with its signals: its ID 2 is also message 'N''s"));
    CHECK(db.find("M") == nullptr);
    CHECK(db.find("O") == nullptr);
    REQUIRE(db.left_out.size() == 2);
    CHECK(db.left_out[1].message == "O");
    CHECK(db.left_out[1].why.text.starts_with("message 'O' was left out"));
    // N stays, and decodes, but which of N and O the frames are is not
    // known: it is marked so that no role may be in it
    REQUIRE(db.find("N") != nullptr);
    REQUIRE(db.find("N")->unread.size() == 1);
    CHECK(db.find("N")->unread[0].where.line == 5);
    CHECK(db.find("N")->signals.size() == 1);  // U went with O
    CHECK(decoded(db, 2, false, {7, 0, 0, 0, 0, 0, 0, 0}) == Values{{"T", 7}});
    CHECK(decoded(db, 3, false, {9}) == Values{{"W", 9}});
  }

  TEST_CASE("an unknown keyword or a stray SG_ line is skipped with a warning") {
    const Database db = parsed(
        "VERSION \"x\"\n"
        "FOO_ bar baz;\n"  // 2: another tool's statement, to its ';'
        "BO_ 1 M: 8 A\n"
        " SG_ S : 0|8@1+ (1,0) [0|255] \"\" B\n"
        " SGX_ T : 8|8@1+ (1,0) [0|255] \"\" B\n"  // 5: a signal mistyped, no ';'
        " SG_ U : 16|8@1+ (1,0) [0|255] \"\" B\n"
        "BO_ 2 N: 1 A\n"
        " SG_ W : 0|8@1+ (1,0) [0|255] \"\" B\n"
        "CM_ \"the file\";\n"
        "BA_DEF_ \"X\" INT 0 1;\n"
        " SG_ V : 0|8@1+ (1,0) [0|255] \"\" B\n");  // 11: after BA_DEF_, no message
    CHECK(warning_lines(db) == std::vector<std::uint32_t>{2, 5, 6, 11});
    CHECK(warned(db, 2, "unknown keyword 'FOO_': skipped"));
    CHECK(warned(db, 11, "SG_ outside a BO_ message: skipped"));
    // the SG_ line after the unknown one is still M's, said so; M can
    // serve no role (the unknown line may have been one of its signals)
    CHECK(warned(db, 6, "read as a signal of message 'M'"));
    const Message* m = db.find("M");
    REQUIRE(m != nullptr);
    CHECK(m->signals.size() == 2);
    REQUIRE(m->unread.size() == 1);
    CHECK(m->unread[0].text == "unknown keyword 'SGX_': skipped");
    CHECK(db.find("N")->unread.empty());
    CHECK(decoded(db, 1, false, {1, 2, 3, 4, 5, 6, 7, 8}) == Values{{"S", 1}, {"U", 3}});
  }

  TEST_CASE("a comment between a message's SG_ lines: the lines after it are still its own") {
    const Database db = parsed(
        "BO_ 1 M: 8 A\n"
        " SG_ S : 0|8@1+ (1,0) [0|255] \"\" B\n"
        "CM_ SG_ 1 S \"speed\";\n"
        " SG_ T : 8|8@1+ (1,0) [0|255] \"\" B\n"  // 4
        "VAL_ 1 T 0 \"off\" 1 \"on\";\n"
        " SG_ U : 16|8@1+ (1,0) [0|255] \"\" B\n"  // 6
        "BO_ 2 N: 1 A\n"
        " SG_ W : 0|8@1+ (1,0) [0|255] \"\" B\n");
    CHECK(warning_lines(db) == std::vector<std::uint32_t>{4, 6});
    const Message* m = db.find("M");
    REQUIRE(m != nullptr);
    CHECK(m->unread.empty());  // read as written: roles may use it
    CHECK(m->find_signal("S")->comment == "speed");
    CHECK(m->find_signal("T")->values.at(1) == "on");
    CHECK(decoded(db, 1, false, {1, 2, 3, 4, 5, 6, 7, 8}) == Values{{"S", 1}, {"T", 2}, {"U", 3}});
    CHECK(decoded(db, 2, false, {9}) == Values{{"W", 9}});
  }

  TEST_CASE("comments and value tables anywhere, stale ones with a warning") {
    const Database db = parsed(
        "VERSION \"\"\n"
        "CM_ BO_ 10 \"before its message\";\n"             // 2
        "VAL_ 10 Gear 0 \"P\" 1 \"R\" 2 \"N\" 3 \"D\";\n"  // 3
        "CM_ SG_ 10 Gear \"a \\\"quoted\\\" word,\n"       // 4: multi-line, escapes
        "over ; two lines\";\n"
        "VAL_TABLE_ Gears 0 \"P\" 1 \"R\";\n"
        "BO_ 10 Trans: 2 A\n"  // 7
        " SG_ Gear : 0|4@1+ (1,0) [0|3] \"\" B\n"
        " SG_ Torque : 8|8@1- (2,0) [0|0] \"Nm\" B\n"
        "CM_ BO_ 99 \"no such message\";\n"      // 10
        "CM_ SG_ 10 Nope \"no such signal\";\n"  // 11
        "VAL_ 99 Gear 0 \"x\";\n"                // 12
        "VAL_ 10 Nope 0 \"x\";\n"                // 13
        "SIG_VALTYPE_ 77 X : 1;\n"               // 14
        "CM_ BU_ A \"a node\";\n"
        "CM_ \"the file\";\n");
    CHECK(warning_lines(db) == std::vector<std::uint32_t>{10, 11, 12, 13, 14});
    CHECK(warned(db, 10, "message 0x63, which the file does not define"));
    CHECK(warned(db, 13, "signal 'Nope', which message 'Trans' does not have"));
    const Message* m = db.find("Trans");
    CHECK(m->comment == "before its message");
    CHECK(m->find_signal("Gear")->comment == "a \"quoted\" word,\nover ; two lines");
    CHECK(m->find_signal("Gear")->values.at(3) == "D");
    CHECK(decoded(db, 10, false, {3, 0xFB}) == Values{{"Gear", 3}, {"Torque", -10}});
  }

  TEST_CASE("keywords in odd spots, empty sections, CRLF and tabs are read") {
    std::string text =
        "VERSION \"\"\n"
        "\n"
        "NS_ :\n"
        "\tNS_DESC_\n"
        "\tCM_\n"
        "\tBA_DEF_DEF_REL_\n"
        "\tBU_SG_REL_\n"
        "\tSG_MUL_VAL_\n"
        "\tSIGTYPE_VALTYPE_\n"
        "BA_SGTYPE_\n"  // some writers put the names at column 1
        "ENVVAR_DATA_\n"
        "\n"
        "BS_: 500 : 12,34\n"
        "BU_:\n"
        "VAL_TABLE_ Empty ;\n"
        "BO_ 200\tBody :\t8\tA\n"
        "\tSG_ Door : 0|2@1+ (1,0) [0|3] \"\"\tB\n"
        "\tSG_ Window : 15|10@0+ (0.1,0) [0|100] \"%\" B,C\n"
        "BO_TX_BU_ 200 : A,B;\n"
        "EV_ EnvA : 0 [0|10] \"\" 0 1 DUMMY_NODE_VECTOR0 Vector__XXX;\n"
        "ENVVAR_DATA_ EnvA : 4;\n"
        "SGTYPE_ T1 : 8@1+ (1,0) [0|255] \"\" 0 , Vals;\n"
        "SIG_TYPE_REF_ 200 Door : T1;\n"
        "SIG_GROUP_ 200 Grp 1 : Door Window;\n"
        "CAT_DEF_ 1 Cat 0;\n"
        "CAT_ BO_ 200 1;\n"
        "FILTER 0 ;\n"
        "BA_DEF_ \"BusType\" STRING ;\n"
        "BA_DEF_ BO_ \"GenMsgCycleTime\" INT 0 65535;\n"
        "BA_DEF_ SG_ \"GenSigStartValue\" FLOAT -1E+030 1E+030;\n"
        "BA_DEF_ BU_ \"NodeLayerModules\" HEX 0 255;\n"
        "BA_DEF_ EV_ \"E\" ENUM \"a;b\",\"c\";\n"
        "BA_DEF_REL_ BU_SG_REL_ \"GenSigTimeoutTime\" INT 0 65535;\n"
        "BA_DEF_DEF_REL_ \"GenSigTimeoutTime\" 0;\n"
        "BA_DEF_DEF_ \"BusType\" \"CAN\";\n"
        "BA_ \"BusType\" \"CAN FD\";\n"
        "BA_ \"GenMsgCycleTime\" BO_ 200 100;\n"
        "BA_REL_ \"GenSigTimeoutTime\" BU_SG_REL_ B SG_ 200 Door 500;\n"
        "BU_SG_REL_ B SG_ 200 Door;\n"
        "BU_EV_REL_ A EnvA;\n"
        "SIG_VALTYPE_ 200 Door : 0;\n"
        ";\n";
    // CRLF line ends throughout
    std::string crlf;
    for (char c : text) crlf += c == '\n' ? std::string("\r\n") : std::string(1, c);
    for (const std::string* t : {&text, &crlf}) {
      const Database db = parsed(*t);
      CHECK(db.warnings.empty());
      CHECK(db.nodes.empty());
      REQUIRE(db.messages.size() == 1);
      const Message* m = db.find("Body");
      REQUIRE(m != nullptr);
      CHECK(m->find_signal("Window")->receivers == std::vector<std::string>{"B", "C"});
      // Window: Motorola, MSB bit 15 (byte 1 bit 7), 10 bits: byte 1, then 2 bits of byte 2
      const Values v = decoded(db, 200, false, {0x02, 0x80, 0x40, 0, 0, 0, 0, 0});
      REQUIRE(v.size() == 2);
      CHECK(v.at("Door") == 2);
      CHECK(v.at("Window") == doctest::Approx(51.3).epsilon(1e-12));
    }
  }

  TEST_CASE("Windows-1252 text in comments and units becomes UTF-8, never an error") {
    const Database db = parsed(
        "BO_ 1 M: 1 A\n"
        " SG_ T : 0|8@1- (1,0) [0|0] \"\xB0"
        "C\" B\n"  // 2: degree sign in cp1252
        "CM_ SG_ 1 T \"Gr\xF6\xDF"
        "e in \x80, \x93quoted\x94\x81\";\n"           // 3
        "CM_ BO_ 1 \"d\xC3\xA9j\xC3\xA0 UTF-8\";\n");  // 4: UTF-8 stays as it is
    CHECK(warning_lines(db) == std::vector<std::uint32_t>{2});
    CHECK(warned(db, 2, "2 strings from this line on"));
    const Message* m = db.find("M");
    CHECK(m->find_signal("T")->unit ==
          "\xC2\xB0"
          "C");
    CHECK(m->find_signal("T")->comment ==
          "Gr\xC3\xB6\xC3\x9F"
          "e in \xE2\x82\xAC, \xE2\x80\x9Cquoted\xE2\x80\x9D\xC2\x81");
    CHECK(m->comment == "d\xC3\xA9j\xC3\xA0 UTF-8");
    CHECK(decoded(db, 1, false, {0xF6}) == Values{{"T", -10}});
  }
}
