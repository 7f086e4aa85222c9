#include "turncal/can/dbc.hpp"

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>

namespace turncal::can {
namespace {

__extension__ typedef unsigned __int128 u128;

constexpr std::uint32_t kDbcExtendedFlag = 0x80000000u;
constexpr std::uint32_t kMaxBits = kMaxFdLen * 8;

// ---------------------------------------------------------------- lexer ----

struct Token {
  enum Kind : std::uint8_t { Ident, Number, String, Punct, End };
  Kind kind = End;
  std::string_view text;  ///< raw text (for String: without quotes, escapes kept)
  std::uint32_t line = 0, column = 0;
  bool line_start = false;  ///< first character of its line (column 1)
};

class Lexer {
 public:
  explicit Lexer(std::string_view text) : s_(text) {}

  const Token& peek() {
    if (!have_) {
      tok_ = lex();
      have_ = true;
    }
    return tok_;
  }
  Token next() {
    peek();
    have_ = false;
    return tok_;
  }
  [[nodiscard]] std::optional<Error> lex_error() const { return err_; }

 private:
  char at(std::size_t i) const { return i < s_.size() ? s_[i] : '\0'; }
  void advance() {
    if (s_[p_] == '\n') {
      ++line_;
      col_ = 1;
    } else {
      ++col_;
    }
    ++p_;
  }
  static bool ident_start(char c) {
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || c == '_';
  }
  static bool digit(char c) { return c >= '0' && c <= '9'; }

  Token lex() {
    for (;;) {  // whitespace and // comments
      while (p_ < s_.size() &&
             (s_[p_] == ' ' || s_[p_] == '\t' || s_[p_] == '\r' || s_[p_] == '\n'))
        advance();
      if (at(p_) == '/' && at(p_ + 1) == '/') {
        while (p_ < s_.size() && s_[p_] != '\n') advance();
        continue;
      }
      break;
    }
    Token t;
    t.line = line_;
    t.column = col_;
    t.line_start = col_ == 1;
    if (p_ >= s_.size()) return t;
    const std::size_t b = p_;
    const char c = s_[p_];
    if (ident_start(c)) {
      while (p_ < s_.size() && (ident_start(s_[p_]) || digit(s_[p_]))) advance();
      t.kind = Token::Ident;
    } else if (digit(c) || ((c == '-' || c == '+') && (digit(at(p_ + 1)) || at(p_ + 1) == '.')) ||
               (c == '.' && digit(at(p_ + 1)))) {
      advance();
      while (p_ < s_.size()) {
        const char d = s_[p_];
        if (digit(d) || d == '.') {
          advance();
        } else if ((d == 'e' || d == 'E') && p_ + 1 < s_.size()) {
          advance();
          if (at(p_) == '+' || at(p_) == '-') advance();
        } else {
          break;
        }
      }
      t.kind = Token::Number;
    } else if (c == '"') {
      advance();
      const std::size_t sb = p_;
      while (p_ < s_.size() && s_[p_] != '"') {
        if (s_[p_] == '\\' && p_ + 1 < s_.size()) advance();
        advance();
      }
      if (p_ >= s_.size()) {
        err_ = make_error("unterminated string", SourcePos{{}, t.line, t.column});
        t.kind = Token::End;
        return t;
      }
      t.kind = Token::String;
      t.text = s_.substr(sb, p_ - sb);
      advance();
      return t;
    } else {
      advance();
      t.kind = Token::Punct;
    }
    t.text = s_.substr(b, p_ - b);
    return t;
  }

  std::string_view s_;
  std::size_t p_ = 0;
  std::uint32_t line_ = 1, col_ = 1;
  Token tok_;
  bool have_ = false;
  std::optional<Error> err_;
};

std::string unescape(std::string_view s) {
  std::string out;
  out.reserve(s.size());
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '\\' && i + 1 < s.size()) ++i;
    out += s[i];
  }
  return out;
}

bool is_keyword(std::string_view w) {
  static constexpr std::string_view kKeywords[] = {"VERSION",
                                                   "NS_",
                                                   "BS_",
                                                   "BU_",
                                                   "BO_",
                                                   "SG_",
                                                   "CM_",
                                                   "VAL_",
                                                   "VAL_TABLE_",
                                                   "SIG_VALTYPE_",
                                                   "BA_DEF_",
                                                   "BA_DEF_DEF_",
                                                   "BA_",
                                                   "BA_DEF_REL_",
                                                   "BA_DEF_DEF_REL_",
                                                   "BA_REL_",
                                                   "BO_TX_BU_",
                                                   "EV_",
                                                   "ENVVAR_DATA_",
                                                   "SIG_GROUP_",
                                                   "SG_MUL_VAL_",
                                                   "SIGTYPE_VALTYPE_",
                                                   "CAT_DEF_",
                                                   "CAT_",
                                                   "FILTER",
                                                   "SIG_TYPE_REF_",
                                                   "SGTYPE_",
                                                   "SGTYPE_VAL_",
                                                   "BA_SGTYPE_",
                                                   "SIG_TYPE_REF_"};
  for (auto k : kKeywords)
    if (w == k) return true;
  return false;
}

// --------------------------------------------------------------- parser ----

class Parser {
 public:
  Parser(std::string_view text, std::string file) : lx_(text), file_(std::move(file)) {}

  Result<Database> run();

 private:
  struct PendingValType {
    std::uint32_t raw_id;
    std::string signal;
    int type;
    std::uint32_t line;
  };
  struct PendingValues {
    std::uint32_t raw_id;
    std::string signal;
    std::map<std::int64_t, std::string> values;
  };
  struct PendingComment {
    std::uint32_t raw_id;
    std::string signal;  // empty: the message
    std::string text;
  };

  Error err(const Token& t, std::string what) const {
    return make_error(std::move(what), SourcePos{file_, t.line, t.column});
  }
  Error unexpected(const Token& t, std::string_view expected) const {
    if (auto e = lx_.lex_error()) {
      Error out = *e;
      out.where.file = file_;
      return out;
    }
    const std::string got = t.kind == Token::End ? "end of file" : "'" + std::string(t.text) + "'";
    return err(t, "expected " + std::string(expected) + ", found " + got);
  }
  Status expect_punct(char c) {
    const Token t = lx_.next();
    if (t.kind != Token::Punct || t.text[0] != c) return unexpected(t, std::string("'") + c + "'");
    return Status{Ok{}};
  }
  Result<Token> expect(Token::Kind kind, std::string_view what) {
    Token t = lx_.next();
    if (t.kind != kind) return unexpected(t, what);
    return t;
  }
  Result<double> number() {
    const Token t = lx_.next();
    if (t.kind != Token::Number) return unexpected(t, "a number");
    double v = 0;
    std::string_view s = t.text;
    if (!s.empty() && s[0] == '+') s.remove_prefix(1);
    auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
    if (ec != std::errc{} || ptr != s.data() + s.size())
      return err(t, "bad number '" + std::string(t.text) + "'");
    return v;
  }
  Result<std::uint64_t> unsigned_number(std::string_view what) {
    const Token t = lx_.next();
    if (t.kind != Token::Number) return unexpected(t, what);
    std::uint64_t v = 0;
    auto [ptr, ec] = std::from_chars(t.text.data(), t.text.data() + t.text.size(), v);
    if (ec != std::errc{} || ptr != t.text.data() + t.text.size())
      return err(t, "expected " + std::string(what) + ", found '" + std::string(t.text) + "'");
    return v;
  }
  Result<std::int64_t> signed_number() {
    const Token t = lx_.next();
    if (t.kind != Token::Number) return unexpected(t, "an integer");
    std::int64_t v = 0;
    std::string_view s = t.text;
    if (!s.empty() && s[0] == '+') s.remove_prefix(1);
    auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
    if (ec != std::errc{} || ptr != s.data() + s.size())
      return err(t, "bad integer '" + std::string(t.text) + "'");
    return v;
  }
  Result<std::uint32_t> message_id() {
    auto v = unsigned_number("a message ID");
    if (!v) return std::move(v).error();
    if (*v > 0xFFFFFFFFu)
      return make_error("message ID out of range", SourcePos{file_, last_line(), 0});
    return static_cast<std::uint32_t>(*v);
  }
  std::uint32_t last_line() { return lx_.peek().line; }

  /// Skips an unknown or ignored statement: up to and including ';', or up
  /// to a keyword at the start of a line.
  void skip_statement() {
    for (;;) {
      const Token& t = lx_.peek();
      if (t.kind == Token::End) return;
      if (t.line_start && t.kind == Token::Ident && is_keyword(t.text)) return;
      const Token n = lx_.next();
      if (n.kind == Token::Punct && n.text == ";") return;
    }
  }
  /// Skips the rest of the line of `line`.
  void skip_line(std::uint32_t line) {
    while (lx_.peek().kind != Token::End && lx_.peek().line == line) lx_.next();
  }

  Status parse_message(const Token& kw);
  Status parse_signal(const Token& kw);
  Status parse_comment();
  Status parse_values();
  Status parse_valtype();
  Status parse_attribute();
  Status finish(Database& db);

  Lexer lx_;
  std::string file_;
  Database db_;
  std::optional<std::size_t> current_;  // index of the message SG_ lines belong to
  std::unordered_map<std::uint32_t, std::size_t> by_raw_id_;
  std::vector<PendingValType> valtypes_;
  std::vector<PendingValues> values_;
  std::vector<PendingComment> comments_;
  std::vector<std::pair<std::uint32_t, int>> frame_formats_;
};

Status Parser::parse_message(const Token& kw) {
  TURNCAL_ASSIGN(raw_id, message_id());
  TURNCAL_ASSIGN(name, expect(Token::Ident, "a message name"));
  TURNCAL_TRY(expect_punct(':'));
  const Token size_tok = lx_.peek();
  TURNCAL_ASSIGN(size, unsigned_number("the message size"));
  if (size > kMaxFdLen || !is_valid_fd_len(size))
    return err(size_tok, "message size " + std::to_string(size) + " is not a CAN or CAN FD length");
  std::string transmitter;
  if (lx_.peek().kind == Token::Ident && lx_.peek().line == kw.line) transmitter = lx_.next().text;
  if (by_raw_id_.count(raw_id) != 0)
    return err(kw, "message ID " + std::to_string(raw_id & ~kDbcExtendedFlag) + " defined twice");
  Message m;
  m.extended = (raw_id & kDbcExtendedFlag) != 0;
  m.id = raw_id & (m.extended ? kExtIdMask : 0xFFFFFFFFu);
  if (!m.extended && m.id > kStdIdMask) return err(kw, "standard message ID above 0x7FF");
  m.name = name.text;
  m.size = static_cast<std::uint32_t>(size);
  m.fd = m.size > kMaxClassicLen;
  m.transmitter = std::move(transmitter);
  m.line = kw.line;
  by_raw_id_[raw_id] = db_.messages.size();
  current_ = db_.messages.size();
  db_.messages.push_back(std::move(m));
  return Status{Ok{}};
}

Status Parser::parse_signal(const Token& kw) {
  if (!current_) return err(kw, "SG_ outside a BO_ message");
  Signal s;
  s.line = kw.line;
  TURNCAL_ASSIGN(name, expect(Token::Ident, "a signal name"));
  s.name = name.text;
  if (lx_.peek().kind == Token::Ident) {
    const Token mux = lx_.next();
    std::string_view m = mux.text;
    if (m == "M") {
      s.mux = MuxRole::Multiplexor;
    } else if (m.size() >= 2 && m[0] == 'm') {
      std::string_view digits = m.substr(1);
      if (digits.back() == 'M') digits.remove_suffix(1);  // extended multiplexing: taken as simple
      std::uint64_t v = 0;
      auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), v);
      if (ec != std::errc{} || ptr != digits.data() + digits.size() || digits.empty())
        return err(mux, "bad multiplexer indicator '" + std::string(m) + "'");
      s.mux = MuxRole::Multiplexed;
      s.mux_value = v;
    } else {
      return err(mux, "bad multiplexer indicator '" + std::string(m) + "'");
    }
  }
  TURNCAL_TRY(expect_punct(':'));
  const Token start_tok = lx_.peek();
  TURNCAL_ASSIGN(start, unsigned_number("the start bit"));
  TURNCAL_TRY(expect_punct('|'));
  TURNCAL_ASSIGN(length, unsigned_number("the signal length"));
  TURNCAL_TRY(expect_punct('@'));
  const Token order_tok = lx_.next();
  if (order_tok.kind != Token::Number || (order_tok.text != "0" && order_tok.text != "1"))
    return unexpected(order_tok, "byte order 0 or 1");
  const Token sign_tok = lx_.next();
  if (sign_tok.kind != Token::Punct || (sign_tok.text != "+" && sign_tok.text != "-"))
    return unexpected(sign_tok, "'+' or '-'");
  TURNCAL_TRY(expect_punct('('));
  TURNCAL_ASSIGN(factor, number());
  TURNCAL_TRY(expect_punct(','));
  TURNCAL_ASSIGN(offset, number());
  TURNCAL_TRY(expect_punct(')'));
  TURNCAL_TRY(expect_punct('['));
  TURNCAL_ASSIGN(minimum, number());
  TURNCAL_TRY(expect_punct('|'));
  TURNCAL_ASSIGN(maximum, number());
  TURNCAL_TRY(expect_punct(']'));
  TURNCAL_ASSIGN(unit, expect(Token::String, "the unit string"));
  if (length < 1 || length > 64) return err(start_tok, "signal length must be 1 to 64 bits");
  if (start >= kMaxBits) return err(start_tok, "start bit out of range");
  if (factor == 0.0) return err(start_tok, "signal factor must not be zero");
  s.start_bit = static_cast<std::uint32_t>(start);
  s.length = static_cast<std::uint32_t>(length);
  s.order = order_tok.text == "1" ? ByteOrder::LittleEndian : ByteOrder::BigEndian;
  s.is_signed = sign_tok.text == "-";
  s.factor = factor;
  s.offset = offset;
  s.minimum = minimum;
  s.maximum = maximum;
  s.unit = unescape(unit.text);
  // receivers: comma-separated names on the same line
  while (lx_.peek().kind == Token::Ident && lx_.peek().line == kw.line && !lx_.peek().line_start) {
    s.receivers.emplace_back(lx_.next().text);
    if (lx_.peek().kind == Token::Punct && lx_.peek().text == "," && lx_.peek().line == kw.line)
      lx_.next();
  }
  Message& m = db_.messages[*current_];
  for (const Signal& other : m.signals)
    if (other.name == s.name) return err(kw, "signal '" + s.name + "' defined twice in " + m.name);
  m.signals.push_back(std::move(s));
  return Status{Ok{}};
}

Status Parser::parse_comment() {
  const Token t = lx_.next();
  if (t.kind == Token::String) return expect_punct(';');
  if (t.kind != Token::Ident) return unexpected(t, "a comment");
  if (t.text == "BO_" || t.text == "SG_") {
    TURNCAL_ASSIGN(raw_id, message_id());
    std::string signal;
    if (t.text == "SG_") {
      TURNCAL_ASSIGN(name, expect(Token::Ident, "a signal name"));
      signal = name.text;
    }
    TURNCAL_ASSIGN(text, expect(Token::String, "the comment string"));
    comments_.push_back({raw_id, std::move(signal), unescape(text.text)});
    return expect_punct(';');
  }
  skip_statement();  // BU_ and EV_ comments
  return Status{Ok{}};
}

Status Parser::parse_values() {
  if (lx_.peek().kind != Token::Number) {  // environment variable tables
    skip_statement();
    return Status{Ok{}};
  }
  TURNCAL_ASSIGN(raw_id, message_id());
  TURNCAL_ASSIGN(name, expect(Token::Ident, "a signal name"));
  PendingValues pv{raw_id, std::string(name.text), {}};
  for (;;) {
    const Token& t = lx_.peek();
    if (t.kind == Token::Punct && t.text == ";") {
      lx_.next();
      break;
    }
    TURNCAL_ASSIGN(v, signed_number());
    TURNCAL_ASSIGN(desc, expect(Token::String, "a value description"));
    pv.values[v] = unescape(desc.text);
  }
  values_.push_back(std::move(pv));
  return Status{Ok{}};
}

Status Parser::parse_valtype() {
  const std::uint32_t line = lx_.peek().line;
  TURNCAL_ASSIGN(raw_id, message_id());
  TURNCAL_ASSIGN(name, expect(Token::Ident, "a signal name"));
  if (lx_.peek().kind == Token::Punct && lx_.peek().text == ":") lx_.next();
  const Token vt = lx_.peek();
  TURNCAL_ASSIGN(type, unsigned_number("a value type 0, 1 or 2"));
  if (type > 2) return err(vt, "SIG_VALTYPE_ must be 0, 1 or 2");
  valtypes_.push_back({raw_id, std::string(name.text), static_cast<int>(type), line});
  return expect_punct(';');
}

Status Parser::parse_attribute() {
  const Token name = lx_.peek();
  if (name.kind == Token::String && name.text == "VFrameFormat") {
    lx_.next();
    const Token obj = lx_.peek();
    if (obj.kind == Token::Ident && obj.text == "BO_") {
      lx_.next();
      TURNCAL_ASSIGN(raw_id, message_id());
      TURNCAL_ASSIGN(value, signed_number());
      frame_formats_.emplace_back(raw_id, static_cast<int>(value));
      return expect_punct(';');
    }
  }
  skip_statement();
  return Status{Ok{}};
}

Status Parser::finish(Database& db) {
  auto find = [&](std::uint32_t raw_id) -> Message* {
    auto it = by_raw_id_.find(raw_id);
    return it == by_raw_id_.end() ? nullptr : &db.messages[it->second];
  };
  auto find_sig = [&](std::uint32_t raw_id, const std::string& name) -> Signal* {
    Message* m = find(raw_id);
    if (m == nullptr) return nullptr;
    for (Signal& s : m->signals)
      if (s.name == name) return &s;
    return nullptr;
  };
  // References to messages or signals the file does not define are left
  // alone, as vendor tools do: stale comments and tables are common.
  for (const auto& v : valtypes_) {
    Signal* s = find_sig(v.raw_id, v.signal);
    if (s == nullptr) continue;
    if (v.type == 1 && s->length != 32)
      return make_error("float signal '" + s->name + "' must be 32 bits",
                        SourcePos{file_, v.line, 0});
    if (v.type == 2 && s->length != 64)
      return make_error("double signal '" + s->name + "' must be 64 bits",
                        SourcePos{file_, v.line, 0});
    s->type = v.type == 1   ? ValueType::Float32
              : v.type == 2 ? ValueType::Float64
                            : ValueType::Integer;
  }
  for (auto& v : values_)
    if (Signal* s = find_sig(v.raw_id, v.signal)) s->values = std::move(v.values);
  for (auto& c : comments_) {
    if (c.signal.empty()) {
      if (Message* m = find(c.raw_id)) m->comment = std::move(c.text);
    } else if (Signal* s = find_sig(c.raw_id, c.signal)) {
      s->comment = std::move(c.text);
    }
  }
  for (auto [raw_id, format] : frame_formats_)
    if (Message* m = find(raw_id)) m->fd = m->fd || format == 14 || format == 15;
  // Vector's placeholder for signals not in any message.
  std::erase_if(db.messages,
                [](const Message& m) { return m.name == "VECTOR__INDEPENDENT_SIG_MSG"; });
  for (Message& m : db.messages) {
    int multiplexors = 0;
    for (Signal& s : m.signals) {
      if (!s.finalize() || s.end_byte() > m.size)
        return make_error("signal '" + s.name + "' (start " + std::to_string(s.start_bit) + ", " +
                              std::to_string(s.length) + " bits) does not fit message '" + m.name +
                              "' of " + std::to_string(m.size) + " bytes",
                          SourcePos{file_, s.line, 0});
      if (s.mux == MuxRole::Multiplexor) ++multiplexors;
    }
    if (multiplexors > 1)
      return make_error("message '" + m.name + "' has more than one multiplexor",
                        SourcePos{file_, m.line, 0});
    for (const Signal& s : m.signals)
      if (s.mux == MuxRole::Multiplexed && multiplexors == 0)
        return make_error(
            "signal '" + s.name + "' is multiplexed but '" + m.name + "' has no multiplexor",
            SourcePos{file_, s.line, 0});
  }
  return Status{Ok{}};
}

Result<Database> Parser::run() {
  for (;;) {
    const Token t = lx_.next();
    if (t.kind == Token::End) {
      if (auto e = lx_.lex_error()) return unexpected(t, "");
      break;
    }
    if (t.kind != Token::Ident) {
      if (t.kind == Token::Punct && t.text == ";") continue;
      return unexpected(t, "a DBC keyword");
    }
    Status st{Ok{}};
    if (t.text == "VERSION") {
      TURNCAL_ASSIGN(v, expect(Token::String, "the version string"));
      db_.version = unescape(v.text);
      db_.version_line = t.line;
    } else if (t.text == "NS_") {
      st = expect_punct(':');
      while (lx_.peek().kind != Token::End && !lx_.peek().line_start) lx_.next();
    } else if (t.text == "BS_") {
      skip_line(t.line);
    } else if (t.text == "BU_") {
      st = expect_punct(':');
      while (st && lx_.peek().kind == Token::Ident && lx_.peek().line == t.line)
        db_.nodes.emplace_back(lx_.next().text);
    } else if (t.text == "BO_") {
      st = parse_message(t);
    } else if (t.text == "SG_") {
      st = parse_signal(t);
    } else if (t.text == "CM_") {
      st = parse_comment();
    } else if (t.text == "VAL_") {
      st = parse_values();
    } else if (t.text == "SIG_VALTYPE_") {
      st = parse_valtype();
    } else if (t.text == "BA_") {
      st = parse_attribute();
    } else if (is_keyword(t.text)) {
      current_.reset();
      skip_statement();
    } else {
      return err(t, "unknown keyword '" + std::string(t.text) + "'");
    }
    if (!st) return std::move(st).error();
    if (t.text != "BO_" && t.text != "SG_") current_.reset();
  }
  TURNCAL_TRY(finish(db_));
  return std::move(db_);
}

std::uint64_t low_mask(std::uint32_t bits) {
  return bits >= 64 ? ~0ull : (1ull << bits) - 1;
}

}  // namespace

// ---------------------------------------------------------------- model ----

bool Signal::finalize() {
  if (length < 1 || length > 64 || start_bit >= kMaxBits) return false;
  if (order == ByteOrder::LittleEndian) {
    const std::uint32_t last = start_bit + length - 1;
    if (last >= kMaxBits) return false;
    first_byte = start_bit / 8;
    span = last / 8 - first_byte + 1;
    shift = start_bit % 8;
  } else {
    // Motorola: the start bit is the MSB; in a big-endian linear numbering
    // (byte*8 + 7 - bit) the signal occupies [msb, msb + length).
    const std::uint32_t msb = (start_bit / 8) * 8 + (7 - start_bit % 8);
    const std::uint32_t lsb = msb + length - 1;
    if (lsb >= kMaxBits) return false;
    first_byte = msb / 8;
    span = lsb / 8 - first_byte + 1;
    shift = 7 - lsb % 8;
  }
  return true;
}

const Signal* Message::find_signal(std::string_view n) const {
  for (const Signal& s : signals)
    if (s.name == n) return &s;
  return nullptr;
}

const Signal* Message::multiplexor() const {
  for (const Signal& s : signals)
    if (s.mux == MuxRole::Multiplexor) return &s;
  return nullptr;
}

const Message* Database::find(std::uint32_t id, bool extended) const {
  for (const Message& m : messages)
    if (m.id == id && m.extended == extended) return &m;
  return nullptr;
}

const Message* Database::find(std::string_view n) const {
  for (const Message& m : messages)
    if (m.name == n) return &m;
  return nullptr;
}

Result<Database> parse_dbc(std::string_view text, const std::string& file) {
  return Parser(text, file).run();
}

Result<Database> load_dbc(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return make_error("cannot open DBC file", SourcePos{path, 0, 0});
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_dbc(ss.str(), path);
}

// ---------------------------------------------------------------- codec ----

std::uint64_t extract_raw(const Signal& sig, std::span<const std::uint8_t> data) {
  u128 acc = 0;
  const std::uint8_t* p = data.data() + sig.first_byte;
  if (sig.order == ByteOrder::LittleEndian) {
    for (std::uint32_t k = sig.span; k-- > 0;) acc = (acc << 8) | p[k];
  } else {
    for (std::uint32_t k = 0; k < sig.span; ++k) acc = (acc << 8) | p[k];
  }
  return static_cast<std::uint64_t>(acc >> sig.shift) & low_mask(sig.length);
}

void insert_raw(const Signal& sig, std::span<std::uint8_t> data, std::uint64_t raw) {
  const u128 mask = static_cast<u128>(low_mask(sig.length)) << sig.shift;
  const u128 bits = (static_cast<u128>(raw & low_mask(sig.length))) << sig.shift;
  std::uint8_t* p = data.data() + sig.first_byte;
  for (std::uint32_t k = 0; k < sig.span; ++k) {
    const std::uint32_t byte_shift =
        sig.order == ByteOrder::LittleEndian ? 8 * k : 8 * (sig.span - 1 - k);
    const auto m = static_cast<std::uint8_t>(mask >> byte_shift);
    const auto b = static_cast<std::uint8_t>(bits >> byte_shift);
    p[k] = static_cast<std::uint8_t>((p[k] & ~m) | b);
  }
}

std::int64_t raw_to_integer(const Signal& sig, std::uint64_t raw) {
  if (sig.is_signed && sig.length < 64 && ((raw >> (sig.length - 1)) & 1u) != 0)
    raw |= ~low_mask(sig.length);
  return static_cast<std::int64_t>(raw);
}

double raw_to_physical(const Signal& sig, std::uint64_t raw) {
  switch (sig.type) {
    case ValueType::Float32:
      return static_cast<double>(std::bit_cast<float>(static_cast<std::uint32_t>(raw))) *
                 sig.factor +
             sig.offset;
    case ValueType::Float64:
      return std::bit_cast<double>(raw) * sig.factor + sig.offset;
    case ValueType::Integer:
      break;
  }
  const double base =
      sig.is_signed ? static_cast<double>(raw_to_integer(sig, raw)) : static_cast<double>(raw);
  return base * sig.factor + sig.offset;
}

namespace {

/// The DBC gives a range unless it is [0|0] (or makes no sense).
bool has_dbc_range(const Signal& sig) {
  return !(sig.minimum == 0 && sig.maximum == 0) && sig.minimum <= sig.maximum;
}

/// The raw integer range of an integer signal.
struct RawBounds {
  long double lo, hi;
};
RawBounds raw_bounds(const Signal& sig) {
  const int n = static_cast<int>(sig.length);
  if (sig.is_signed) return {-std::ldexp(1.0L, n - 1), std::ldexp(1.0L, n - 1) - 1};
  return {0, std::ldexp(1.0L, n) - 1};
}

/// A value's nearest raw step, clamped to the raw range, and whether it
/// needed no clamping and lies in the DBC's range.
struct RawStep {
  std::uint64_t raw = 0;
  bool fits = false;
};

RawStep to_raw(const Signal& sig, double value) {
  auto in_dbc = [&] {
    return !has_dbc_range(sig) || (value >= sig.minimum && value <= sig.maximum);
  };
  switch (sig.type) {
    case ValueType::Float32: {
      const double scaled = (value - sig.offset) / sig.factor;
      const auto f = static_cast<float>(scaled);
      const bool finite = std::isfinite(f) || !std::isfinite(scaled);  // no overflow to inf
      return {std::bit_cast<std::uint32_t>(f), !std::isnan(value) && finite && in_dbc()};
    }
    case ValueType::Float64:
      return {std::bit_cast<std::uint64_t>((value - sig.offset) / sig.factor),
              !std::isnan(value) && in_dbc()};
    case ValueType::Integer:
      break;
  }
  if (std::isnan(value)) return {0, false};
  const long double scaled =
      std::nearbyint((static_cast<long double>(value) - static_cast<long double>(sig.offset)) /
                     static_cast<long double>(sig.factor));
  const auto [lo, hi] = raw_bounds(sig);
  const long double c = scaled > hi ? hi : scaled < lo ? lo : scaled;
  // the DBC range, on the step the value encodes to (a value within half
  // a step of an end encodes to the end)
  const double step = static_cast<double>(c * static_cast<long double>(sig.factor) +
                                          static_cast<long double>(sig.offset));
  const double slack = std::abs(sig.factor) * 1e-6;
  const bool in_range =
      !has_dbc_range(sig) || (step >= sig.minimum - slack && step <= sig.maximum + slack);
  const std::uint64_t raw =
      sig.is_signed
          ? static_cast<std::uint64_t>(static_cast<std::int64_t>(c)) & low_mask(sig.length)
          : static_cast<std::uint64_t>(c);
  return {raw, c == scaled && in_range};
}

/// Decimals of the signal's step (0.01: 2; 1e-5: 5; 2^-32 rev in deg: 8).
int step_decimals(const Signal& sig) {
  const double f = std::abs(sig.factor);
  if (!(f > 0) || f >= 1) return 0;
  return std::min(12, static_cast<int>(std::ceil(-std::log10(f) - 1e-9)));
}

std::string number(double v, int decimals) {
  char buf[64];
  if (std::isfinite(v) && std::abs(v) < 1e15)
    std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  else
    std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

std::string with_unit(const Signal& sig, std::string text) {
  return sig.unit.empty() ? text : text + " " + sig.unit;
}

/// "30000 deg does not fit TBL_Command.Target (-21474.83648 to 21474.83647 deg)"
std::string misfit(const Signal& sig, const std::string& name, double value) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.12g", value);
  return with_unit(sig, buf) + " does not fit " + name + " (" + describe_range(sig) + ")";
}

}  // namespace

PhysicalRange physical_range(const Signal& sig) {
  const double inf = std::numeric_limits<double>::infinity();
  PhysicalRange r{-inf, inf};
  if (sig.type == ValueType::Integer) {
    const auto [lo, hi] = raw_bounds(sig);
    const auto a = static_cast<double>(lo * static_cast<long double>(sig.factor) +
                                       static_cast<long double>(sig.offset));
    const auto b = static_cast<double>(hi * static_cast<long double>(sig.factor) +
                                       static_cast<long double>(sig.offset));
    r = {std::min(a, b), std::max(a, b)};
  } else if (sig.type == ValueType::Float32) {
    const double m = static_cast<double>(std::numeric_limits<float>::max()) * std::abs(sig.factor);
    r = {sig.offset - m, sig.offset + m};
  }
  if (has_dbc_range(sig)) r = {std::max(r.lo, sig.minimum), std::min(r.hi, sig.maximum)};
  return r;
}

std::string describe_range(const Signal& sig) {
  const PhysicalRange r = physical_range(sig);
  const int d = step_decimals(sig);
  return with_unit(sig, number(r.lo, d) + " to " + number(r.hi, d));
}

bool fits(const Signal& sig, double value) {
  return to_raw(sig, value).fits;
}

Result<std::uint64_t> physical_to_raw(const Signal& sig, double value) {
  const RawStep r = to_raw(sig, value);
  if (!r.fits) return make_error(misfit(sig, "signal " + sig.name, value));
  return r.raw;
}

FrameCodec::FrameCodec(const Database& db) : db_(&db) {
  index_.reserve(db.messages.size() * 2);
  for (std::size_t i = 0; i < db.messages.size(); ++i) {
    const Message& m = db.messages[i];
    index_[m.id | (m.extended ? kDbcExtendedFlag : 0u)] = static_cast<std::uint32_t>(i);
  }
}

const Message* FrameCodec::message_for(const Frame& f) const {
  auto it = index_.find(f.id | (f.extended ? kDbcExtendedFlag : 0u));
  return it == index_.end() ? nullptr : &db_->messages[it->second];
}

DecodeStatus FrameCodec::check(const Frame& f, const Message** msg) const {
  if (f.error || f.remote) return DecodeStatus::NotData;
  const Message* m = message_for(f);
  if (m == nullptr) return DecodeStatus::UnknownId;
  if (f.len != m->size) return DecodeStatus::LengthMismatch;
  *msg = m;
  return DecodeStatus::Ok;
}

DecodeStatus FrameCodec::decode(const Frame& f, std::span<double> out, const Message** msg) const {
  const Message* m = nullptr;
  const DecodeStatus st = check(f, &m);
  if (st != DecodeStatus::Ok) return st;
  if (msg != nullptr) *msg = m;
  const std::span<const std::uint8_t> payload(f.data.data(), f.len);
  std::optional<std::uint64_t> selector;
  if (const Signal* mux = m->multiplexor()) selector = extract_raw(*mux, payload);
  for (std::size_t i = 0; i < m->signals.size() && i < out.size(); ++i) {
    const Signal& s = m->signals[i];
    if (s.mux == MuxRole::Multiplexed && s.mux_value != *selector) {
      out[i] = std::numeric_limits<double>::quiet_NaN();
      continue;
    }
    out[i] = raw_to_physical(s, extract_raw(s, payload));
  }
  return DecodeStatus::Ok;
}

namespace {

/// The frame of `msg` from `values`; the index of the first signal whose
/// value does not fit, or -1.
Frame build(const Message& msg, std::span<const double> values, std::ptrdiff_t& misfit_at) {
  misfit_at = -1;
  Frame f;
  f.id = msg.id;
  f.extended = msg.extended;
  f.fd = msg.fd;
  f.len = static_cast<std::uint8_t>(msg.size);
  const std::span<std::uint8_t> payload(f.data.data(), f.len);
  auto note = [&](std::size_t i, bool ok) {
    if (!ok && misfit_at < 0) misfit_at = static_cast<std::ptrdiff_t>(i);
  };
  std::optional<std::uint64_t> selector;
  for (std::size_t i = 0; i < msg.signals.size() && i < values.size(); ++i)
    if (msg.signals[i].mux == MuxRole::Multiplexor) {
      if (std::isnan(values[i])) {
        selector = 0;  // its bits stay 0
        continue;
      }
      const RawStep r = to_raw(msg.signals[i], values[i]);
      note(i, r.fits);
      selector = r.raw;
    }
  for (std::size_t i = 0; i < msg.signals.size() && i < values.size(); ++i) {
    const Signal& s = msg.signals[i];
    if (std::isnan(values[i])) continue;
    if (s.mux == MuxRole::Multiplexed && (!selector || s.mux_value != *selector)) continue;
    const RawStep r = to_raw(s, values[i]);
    note(i, r.fits);
    insert_raw(s, payload, r.raw);
  }
  return f;
}

}  // namespace

Result<Frame> FrameCodec::encode_checked(const Message& msg, std::span<const double> values) {
  std::ptrdiff_t bad = -1;
  Frame f = build(msg, values, bad);
  if (bad >= 0) {
    const auto i = static_cast<std::size_t>(bad);
    return make_error(misfit(msg.signals[i], msg.name + "." + msg.signals[i].name, values[i]));
  }
  return f;
}

Frame FrameCodec::encode(const Message& msg, std::span<const double> values) {
  std::ptrdiff_t bad = -1;
  return build(msg, values, bad);
}

}  // namespace turncal::can
