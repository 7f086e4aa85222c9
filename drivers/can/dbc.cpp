#include "turncal/can/dbc.hpp"

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
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
  explicit Lexer(std::string_view text) : s_(text) {
    if (s_.starts_with("\xEF\xBB\xBF")) p_ = 3;  // a UTF-8 byte order mark
  }

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

/// Length of the UTF-8 sequence at s[i], or 0 when it is not one.
std::size_t utf8_sequence(std::string_view s, std::size_t i) {
  const auto b = [&](std::size_t k) { return static_cast<unsigned char>(s[k]); };
  const unsigned c = b(i);
  std::size_t n = 0;
  unsigned min = 0;
  if (c < 0x80) return 1;
  if (c >= 0xC2 && c <= 0xDF) {
    n = 2;
    min = 0x80;
  } else if (c >= 0xE0 && c <= 0xEF) {
    n = 3;
    min = 0x800;
  } else if (c >= 0xF0 && c <= 0xF4) {
    n = 4;
    min = 0x10000;
  } else {
    return 0;
  }
  if (i + n > s.size()) return 0;
  unsigned cp = c & (0x7Fu >> n);
  for (std::size_t k = 1; k < n; ++k) {
    if ((b(i + k) & 0xC0u) != 0x80u) return 0;
    cp = (cp << 6) | (b(i + k) & 0x3Fu);
  }
  if (cp < min || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return 0;
  return n;
}

bool valid_utf8(std::string_view s) {
  for (std::size_t i = 0; i < s.size();) {
    const std::size_t n = utf8_sequence(s, i);
    if (n == 0) return false;
    i += n;
  }
  return true;
}

void append_utf8(std::string& out, unsigned cp) {
  if (cp < 0x80) {
    out += static_cast<char>(cp);
  } else if (cp < 0x800) {
    out += static_cast<char>(0xC0 | (cp >> 6));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  } else {
    out += static_cast<char>(0xE0 | (cp >> 12));
    out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  }
}

/// Windows-1252 to UTF-8. 0x80..0x9F per the code page (its five unassigned
/// bytes as the C1 controls of the same number, as Windows converts them),
/// 0xA0..0xFF as Latin-1.
std::string cp1252_to_utf8(std::string_view s) {
  static constexpr std::uint16_t kHigh[32] = {
      0x20AC, 0x0081, 0x201A, 0x0192, 0x201E, 0x2026, 0x2020, 0x2021, 0x02C6, 0x2030, 0x0160,
      0x2039, 0x0152, 0x008D, 0x017D, 0x008F, 0x0090, 0x2018, 0x2019, 0x201C, 0x201D, 0x2022,
      0x2013, 0x2014, 0x02DC, 0x2122, 0x0161, 0x203A, 0x0153, 0x009D, 0x017E, 0x0178};
  std::string out;
  out.reserve(s.size() + s.size() / 2);
  for (const char ch : s) {
    const auto c = static_cast<unsigned char>(ch);
    append_utf8(out, c >= 0x80 && c < 0xA0 ? kHigh[c - 0x80] : c);
  }
  return out;
}

/// A string's text: escapes resolved (a backslash keeps the next
/// character), CRLF line ends as LF.
std::string unescape(std::string_view s) {
  std::string out;
  out.reserve(s.size());
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '\\' && i + 1 < s.size()) ++i;
    if (s[i] == '\r' && i + 1 < s.size() && s[i + 1] == '\n') continue;
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
                                                   "BU_SG_REL_",
                                                   "BU_EV_REL_",
                                                   "BU_BO_REL_",
                                                   "EV_DATA_",
                                                   "ENVVAR_DATA_",
                                                   "BA_DEF_SGTYPE_",
                                                   "NS_DESC_",
                                                   "SIGTYPE_VALTYPE_"};
  for (auto k : kKeywords)
    if (w == k) return true;
  return false;
}

// --------------------------------------------------------------- parser ----

/// The key a message is known by: its ID with the DBC's extended flag. An ID
/// above 0x7FF written without the flag is read as extended, as Vector's
/// tools and canmatrix read it.
std::uint32_t canonical_id(std::uint32_t raw_id) {
  if ((raw_id & kDbcExtendedFlag) == 0 && raw_id > kStdIdMask && raw_id <= kExtIdMask)
    return raw_id | kDbcExtendedFlag;
  return raw_id;
}

constexpr std::string_view kIndependentSignals = "VECTOR__INDEPENDENT_SIG_MSG";

class Parser {
 public:
  Parser(std::string_view text, std::string file) : lx_(text), file_(std::move(file)) {}

  Result<Database> run();

 private:
  struct PendingValType {
    std::uint32_t key;
    std::string signal;
    int type;
    std::uint32_t line;
  };
  struct PendingValues {
    std::uint32_t key;
    std::string signal;
    std::map<std::int64_t, std::string> values;
    std::uint32_t line;
  };
  struct PendingComment {
    std::uint32_t key;
    std::string signal;  // empty: the message
    std::string text;
    std::uint32_t line;
  };
  struct PendingLongName {
    std::uint32_t key;
    std::string signal;  // empty: the message
    std::string name;
    std::uint32_t line;
  };
  struct PendingMuxValues {
    std::uint32_t key;
    std::string signal;
    std::string multiplexor;
    std::vector<MuxRange> ranges;
    std::uint32_t line;
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
  void warn(std::uint32_t line, std::string text,
            Diagnostic::Severity sev = Diagnostic::Severity::Warning) {
    db_.warnings.push_back(Diagnostic{sev, SourcePos{file_, line, 0}, std::move(text)});
  }
  /// A string token's text in UTF-8: escapes resolved, and where it is not
  /// UTF-8, read as Windows-1252 (what Vector's Windows tools write).
  std::string text_of(const Token& t) {
    std::string s = unescape(t.text);
    if (valid_utf8(s)) return s;
    if (non_utf8_strings_++ == 0) first_non_utf8_line_ = t.line;
    return cp1252_to_utf8(s);
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
  /// A message ID as written (with the extended flag where written).
  Result<std::uint32_t> message_id() {
    const Token t = lx_.peek();
    auto v = unsigned_number("a message ID");
    if (!v) return std::move(v).error();
    if (*v > 0xFFFFFFFFu) return err(t, "message ID out of range");
    return static_cast<std::uint32_t>(*v);
  }
  /// A reference to a message: its key (canonical_id).
  Result<std::uint32_t> message_ref() {
    auto v = message_id();
    if (!v) return v;
    return canonical_id(*v);
  }

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
  /// Skips an unknown statement begun on `line`: to its ';', or to the
  /// next line whose first word is a keyword (indented or not).
  void skip_unknown(std::uint32_t line) {
    std::uint32_t prev = line;
    for (;;) {
      const Token& t = lx_.peek();
      if (t.kind == Token::End) return;
      if (t.line != prev && t.kind == Token::Ident && is_keyword(t.text)) return;
      const Token n = lx_.next();
      prev = n.line;
      if (n.kind == Token::Punct && n.text == ";") return;
    }
  }
  /// Skips the rest of the line of `line`.
  void skip_line(std::uint32_t line) {
    while (lx_.peek().kind != Token::End && lx_.peek().line == line) lx_.next();
  }
  /// The names of NS_: indented words, or a keyword alone on its line at
  /// column 1 (some writers do not indent them).
  void skip_new_symbols() {
    for (;;) {
      const Token& p = lx_.peek();
      if (p.kind == Token::End) return;
      if (!p.line_start) {
        lx_.next();
        continue;
      }
      if (p.kind != Token::Ident || !(is_keyword(p.text) || p.text.ends_with('_'))) return;
      Lexer probe = lx_;
      const std::uint32_t line = p.line;
      probe.next();
      const Token& q = probe.peek();
      if (q.kind != Token::End && q.line == line) return;  // a statement, not a name
      lx_.next();
    }
  }

  Status parse_message(const Token& kw);
  Status parse_signal(const Token& kw);
  Status parse_comment();
  Status parse_values();
  Status parse_valtype();
  Status parse_attribute();
  Status parse_mux_values(const Token& kw);
  Status finish(Database& db);
  void resolve_multiplexing(Message& m);

  Lexer lx_;
  std::string file_;
  Database db_;
  std::optional<std::size_t> current_;  // index of the message SG_ lines belong to
  bool discarding_ = false;             // the SG_ lines of a message left out follow
  bool interrupted_ = false;            // a CM_, VAL_, BA_ ... came since the last SG_ line
  std::unordered_map<std::uint32_t, std::size_t> by_key_;
  std::vector<PendingValType> valtypes_;
  std::vector<PendingValues> values_;
  std::vector<PendingComment> comments_;
  std::vector<PendingLongName> long_names_;
  std::vector<PendingMuxValues> mux_values_;
  std::vector<std::pair<std::uint32_t, int>> frame_formats_;
  std::size_t non_utf8_strings_ = 0;
  std::uint32_t first_non_utf8_line_ = 0;
};

Status Parser::parse_message(const Token& kw) {
  const Token id_tok = lx_.peek();
  TURNCAL_ASSIGN(raw_id, message_id());
  TURNCAL_ASSIGN(name, expect(Token::Ident, "a message name"));
  TURNCAL_TRY(expect_punct(':'));
  TURNCAL_ASSIGN(size, unsigned_number("the message size"));
  discarding_ = false;
  interrupted_ = false;
  // what makes a message unusable leaves it out, its SG_ lines with it,
  // with a warning; a role naming it is refused with the reason
  std::string left_out;
  if (size > kMaxFdLen || !is_valid_fd_len(size))
    left_out = "message size " + std::to_string(size) + " is not a CAN or CAN FD length";
  std::string transmitter;
  if (lx_.peek().kind == Token::Ident && lx_.peek().line == kw.line) transmitter = lx_.next().text;
  const bool independent = name.text == kIndependentSignals;
  const std::uint32_t key = canonical_id(raw_id);
  Message m;
  m.extended = (key & kDbcExtendedFlag) != 0;
  m.id = key & ~kDbcExtendedFlag;
  if (!independent) {
    if (!m.extended && m.id > kStdIdMask)
      return err(id_tok, "message ID " + std::to_string(raw_id) +
                             " is above 0x1FFFFFFF and has no extended flag (bit 31)");
    if (m.extended && m.id > kExtIdMask) return err(id_tok, "extended message ID above 0x1FFFFFFF");
    if (key != raw_id) {
      char hex[16];
      std::snprintf(hex, sizeof hex, "0x%X", m.id);
      warn(kw.line, "message '" + std::string(name.text) + "': ID " + hex +
                        " is above 0x7FF without the extended flag (bit 31): read as extended");
    }
  }
  if (left_out.empty() && by_key_.count(key) != 0) {
    // which of the two the frames are is not known: neither may serve a role
    Message& first = db_.messages[by_key_[key]];
    left_out = "its ID " + std::to_string(m.id) + " is also message '" + first.name + "''s (line " +
               std::to_string(first.line) + ")";
    first.unread.push_back(Diagnostic{Diagnostic::Severity::Warning, SourcePos{file_, kw.line, 0},
                                      "its ID " + std::to_string(m.id) +
                                          " is defined again, by message '" +
                                          std::string(name.text) + "'"});
  }
  if (!left_out.empty()) {
    warn(kw.line,
         "message '" + std::string(name.text) + "' left out with its signals: " + left_out);
    db_.left_out.push_back(
        {std::string(name.text),
         Diagnostic{Diagnostic::Severity::Warning, SourcePos{file_, kw.line, 0},
                    "message '" + std::string(name.text) + "' was left out: " + left_out}});
    current_.reset();
    discarding_ = true;
    return Status{Ok{}};
  }
  m.name = name.text;
  m.size = static_cast<std::uint32_t>(size);
  m.fd = m.size > kMaxClassicLen;
  m.transmitter = std::move(transmitter);
  m.file = file_;
  m.line = kw.line;
  by_key_[key] = db_.messages.size();
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
      if (digits.back() == 'M') {  // extended multiplexing: multiplexed and a multiplexor
        digits.remove_suffix(1);
        s.multiplexor_too = true;
      }
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
  // what cannot be decoded is kept, unusable: a role that names it is refused
  if (length < 1 || length > 64) {
    s.usable = false;
    s.problem = "its length " + std::to_string(length) + " is not 1 to 64 bits";
  } else if (start >= kMaxBits) {
    s.usable = false;
    s.problem = "its start bit " + std::to_string(start) + " is beyond any CAN FD frame";
  } else if (factor == 0.0 || !std::isfinite(factor) || !std::isfinite(offset)) {
    s.usable = false;
    s.problem = "its factor is zero or its scaling not a number";
  }
  s.start_bit = static_cast<std::uint32_t>(std::min<std::uint64_t>(start, kMaxBits));
  s.length = static_cast<std::uint32_t>(std::min<std::uint64_t>(length, 65));
  s.order = order_tok.text == "1" ? ByteOrder::LittleEndian : ByteOrder::BigEndian;
  s.is_signed = sign_tok.text == "-";
  s.factor = factor;
  s.offset = offset;
  s.minimum = minimum;
  s.maximum = maximum;
  s.unit = text_of(unit);
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
    TURNCAL_ASSIGN(key, message_ref());
    std::string signal;
    if (t.text == "SG_") {
      TURNCAL_ASSIGN(name, expect(Token::Ident, "a signal name"));
      signal = name.text;
    }
    TURNCAL_ASSIGN(text, expect(Token::String, "the comment string"));
    comments_.push_back({key, std::move(signal), text_of(text), t.line});
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
  const std::uint32_t line = lx_.peek().line;
  TURNCAL_ASSIGN(key, message_ref());
  TURNCAL_ASSIGN(name, expect(Token::Ident, "a signal name"));
  PendingValues pv{key, std::string(name.text), {}, line};
  for (;;) {
    const Token& t = lx_.peek();
    if (t.kind == Token::Punct && t.text == ";") {
      lx_.next();
      break;
    }
    TURNCAL_ASSIGN(v, signed_number());
    TURNCAL_ASSIGN(desc, expect(Token::String, "a value description"));
    pv.values[v] = text_of(desc);
  }
  values_.push_back(std::move(pv));
  return Status{Ok{}};
}

Status Parser::parse_valtype() {
  const std::uint32_t line = lx_.peek().line;
  TURNCAL_ASSIGN(key, message_ref());
  TURNCAL_ASSIGN(name, expect(Token::Ident, "a signal name"));
  if (lx_.peek().kind == Token::Punct && lx_.peek().text == ":") lx_.next();
  const Token vt = lx_.peek();
  TURNCAL_ASSIGN(type, unsigned_number("a value type 0, 1 or 2"));
  if (type > 2) return err(vt, "SIG_VALTYPE_ must be 0, 1 or 2");
  valtypes_.push_back({key, std::string(name.text), static_cast<int>(type), line});
  return expect_punct(';');
}

Status Parser::parse_attribute() {
  const Token name = lx_.peek();
  if (name.kind != Token::String) {
    skip_statement();
    return Status{Ok{}};
  }
  const std::string_view attr = name.text;
  if (attr == "VFrameFormat" && lx_.next().kind == Token::String &&
      lx_.peek().kind == Token::Ident && lx_.peek().text == "BO_") {
    lx_.next();
    TURNCAL_ASSIGN(key, message_ref());
    TURNCAL_ASSIGN(value, signed_number());
    frame_formats_.emplace_back(key, static_cast<int>(value));
    return expect_punct(';');
  }
  // The names Vector's tools cut to 32 characters in the file, in full.
  if (attr == "SystemMessageLongSymbol" || attr == "SystemSignalLongSymbol" ||
      attr == "SystemNodeLongSymbol" || attr == "SystemEnvVarLongSymbol") {
    lx_.next();
    const Token obj = lx_.next();
    if (obj.kind != Token::Ident) return unexpected(obj, "BO_, SG_, BU_ or EV_");
    if (obj.text == "BO_" || obj.text == "SG_") {
      TURNCAL_ASSIGN(key, message_ref());
      std::string signal;
      if (obj.text == "SG_") {
        TURNCAL_ASSIGN(sig, expect(Token::Ident, "a signal name"));
        signal = sig.text;
      }
      TURNCAL_ASSIGN(value, expect(Token::String, "the long name"));
      long_names_.push_back({key, std::move(signal), text_of(value), name.line});
    } else if (obj.text == "BU_") {
      TURNCAL_ASSIGN(node, expect(Token::Ident, "a node name"));
      TURNCAL_ASSIGN(value, expect(Token::String, "the long name"));
      db_.node_long_names[std::string(node.text)] = text_of(value);
    } else if (obj.text == "EV_") {
      TURNCAL_ASSIGN(env, expect(Token::Ident, "an environment variable name"));
      TURNCAL_TRY(expect(Token::String, "the long name"));
      warn(name.line,
           "long name of environment variable '" + std::string(env.text) +
               "' skipped: environment variables are not read",
           Diagnostic::Severity::Note);
    } else {
      return unexpected(obj, "BO_, SG_, BU_ or EV_");
    }
    return expect_punct(';');
  }
  skip_statement();
  return Status{Ok{}};
}

// SG_MUL_VAL_ <message ID> <signal> <multiplexor> <lo>-<hi>, ... ;
Status Parser::parse_mux_values(const Token& kw) {
  TURNCAL_ASSIGN(key, message_ref());
  TURNCAL_ASSIGN(sig, expect(Token::Ident, "a signal name"));
  TURNCAL_ASSIGN(mux, expect(Token::Ident, "a multiplexor name"));
  PendingMuxValues pm{key, std::string(sig.text), std::string(mux.text), {}, kw.line};
  for (;;) {
    TURNCAL_ASSIGN(lo, unsigned_number("a multiplexor value"));
    // "3-5" reads as the numbers 3 and -5; "3 - 5" as 3, '-', 5
    const Token t = lx_.next();
    std::uint64_t hi = 0;
    if (t.kind == Token::Number && t.text.starts_with('-')) {
      const std::string_view d = t.text.substr(1);
      auto [ptr, ec] = std::from_chars(d.data(), d.data() + d.size(), hi);
      if (ec != std::errc{} || ptr != d.data() + d.size())
        return err(t, "bad multiplexor value range end '" + std::string(t.text) + "'");
    } else if (t.kind == Token::Punct && t.text == "-") {
      TURNCAL_ASSIGN(h, unsigned_number("a multiplexor value"));
      hi = h;
    } else {
      return unexpected(t, "'-' and the range's end");
    }
    if (lo > hi)
      warn(kw.line, "SG_MUL_VAL_ of '" + pm.signal + "': empty range " + std::to_string(lo) + "-" +
                        std::to_string(hi) + " skipped");
    else
      pm.ranges.push_back({lo, hi});
    const Token sep = lx_.next();
    if (sep.kind == Token::Punct && sep.text == ";") break;
    if (sep.kind != Token::Punct || sep.text != ",") return unexpected(sep, "',' or ';'");
  }
  mux_values_.push_back(std::move(pm));
  return Status{Ok{}};
}

namespace {

std::string hex_id(std::uint32_t key) {
  char buf[24];
  std::snprintf(buf, sizeof buf, "0x%X%s", key & ~kDbcExtendedFlag,
                (key & kDbcExtendedFlag) != 0 ? " (extended)" : "");
  return buf;
}

}  // namespace

// Which multiplexor selects each multiplexed signal, and by which values:
// SG_MUL_VAL_ where the file has it, else the simple rule (the message's
// one multiplexor `M`, the value of `m3`). A signal whose multiplexor is
// unknown, ambiguous, unusable or part of a loop is unusable.
void Parser::resolve_multiplexing(Message& m) {
  const std::uint32_t key = m.id | (m.extended ? kDbcExtendedFlag : 0u);
  auto index_of = [&](std::string_view n) -> std::int32_t {
    for (std::size_t i = 0; i < m.signals.size(); ++i)
      if (m.signals[i].name == n) return static_cast<std::int32_t>(i);
    return -1;
  };
  auto unusable = [&](Signal& s, std::string why) {
    if (!s.usable) return;
    s.usable = false;
    s.problem = std::move(why);
    warn(s.line, "signal '" + m.name + "." + s.name + "' left out: " + s.problem);
  };
  std::vector<bool> explicit_mux(m.signals.size(), false);
  for (const PendingMuxValues& pm : mux_values_) {
    if (pm.key != key) continue;
    const std::int32_t i = index_of(pm.signal);
    if (i < 0) {
      warn(pm.line, "SG_MUL_VAL_ for signal '" + pm.signal + "' that message '" + m.name +
                        "' does not have: skipped");
      continue;
    }
    Signal& s = m.signals[static_cast<std::size_t>(i)];
    if (s.mux != MuxRole::Multiplexed) {
      warn(pm.line, "SG_MUL_VAL_ for signal '" + m.name + "." + s.name +
                        "', which is not multiplexed (no mN): skipped");
      continue;
    }
    const std::int32_t j = index_of(pm.multiplexor);
    if (j < 0 || !m.signals[static_cast<std::size_t>(j)].is_multiplexor()) {
      unusable(s, "its SG_MUL_VAL_ (line " + std::to_string(pm.line) + ") names '" +
                      pm.multiplexor + "', which is no multiplexor of '" + m.name + "'");
      continue;
    }
    if (explicit_mux[static_cast<std::size_t>(i)] && s.selector != j) {
      unusable(s, "SG_MUL_VAL_ lines give it two multiplexors");
      continue;
    }
    explicit_mux[static_cast<std::size_t>(i)] = true;
    s.selector = j;
    s.selected_by.insert(s.selected_by.end(), pm.ranges.begin(), pm.ranges.end());
  }
  std::vector<std::int32_t> plain;  // `M` signals
  for (std::size_t i = 0; i < m.signals.size(); ++i)
    if (m.signals[i].mux == MuxRole::Multiplexor) plain.push_back(static_cast<std::int32_t>(i));
  for (std::size_t i = 0; i < m.signals.size(); ++i) {
    Signal& s = m.signals[i];
    if (s.mux != MuxRole::Multiplexed || explicit_mux[i]) continue;
    if (plain.empty()) {
      unusable(s, "it is multiplexed but '" + m.name + "' has no multiplexor");
    } else if (plain.size() > 1) {
      unusable(
          s, "'" + m.name + "' has several multiplexors and no SG_MUL_VAL_ says which selects it");
    } else {
      s.selector = plain[0];
      s.selected_by = {MuxRange{s.mux_value, s.mux_value}};
    }
  }
  // chains: each multiplexor usable, no loops (until nothing changes)
  for (bool changed = true; changed;) {
    changed = false;
    for (Signal& s : m.signals) {
      if (!s.usable || s.selector < 0) continue;
      std::int32_t j = s.selector;
      std::size_t steps = 0;
      while (j >= 0 && steps <= m.signals.size() && m.signals[static_cast<std::size_t>(j)].usable) {
        j = m.signals[static_cast<std::size_t>(j)].selector;
        ++steps;
      }
      if (j >= 0) {
        const Signal& at = m.signals[static_cast<std::size_t>(j)];
        unusable(s, steps > m.signals.size() ? "its multiplexors select each other in a loop"
                                             : "its multiplexor chain goes through '" + at.name +
                                                   "', which is unusable");
        changed = true;
      }
    }
  }
}

Status Parser::finish(Database& db) {
  auto find = [&](std::uint32_t key) -> Message* {
    auto it = by_key_.find(key);
    return it == by_key_.end() ? nullptr : &db.messages[it->second];
  };
  auto find_sig = [&](std::uint32_t key, const std::string& name) -> Signal* {
    Message* m = find(key);
    if (m == nullptr) return nullptr;
    for (Signal& s : m->signals)
      if (s.name == name) return &s;
    return nullptr;
  };
  // References to messages or signals the file does not define are kept
  // out with a warning, as vendor tools do: stale comments and tables are
  // common.
  auto stale = [&](std::uint32_t line, std::string_view what, std::uint32_t key,
                   const std::string& signal) {
    const Message* m = find(key);
    if (m == nullptr)
      warn(line, std::string(what) + " for message " + hex_id(key) +
                     ", which the file does not define: skipped");
    else
      warn(line, std::string(what) + " for signal '" + signal + "', which message '" + m->name +
                     "' does not have: skipped");
  };
  for (const auto& v : valtypes_) {
    Signal* s = find_sig(v.key, v.signal);
    if (s == nullptr) {
      stale(v.line, "SIG_VALTYPE_", v.key, v.signal);
      continue;
    }
    const std::uint32_t bits = v.type == 1 ? 32 : 64;
    if (v.type != 0 && s->length != bits) {
      if (s->usable) {
        s->usable = false;
        s->problem = std::string(v.type == 1 ? "float" : "double") + " (SIG_VALTYPE_ line " +
                     std::to_string(v.line) + ") but " + std::to_string(s->length) + " bits, not " +
                     std::to_string(bits);
      }
      continue;
    }
    s->type = v.type == 1   ? ValueType::Float32
              : v.type == 2 ? ValueType::Float64
                            : ValueType::Integer;
  }
  for (auto& v : values_) {
    if (Signal* s = find_sig(v.key, v.signal))
      s->values = std::move(v.values);
    else
      stale(v.line, "VAL_", v.key, v.signal);
  }
  for (auto& c : comments_) {
    if (c.signal.empty()) {
      if (Message* m = find(c.key))
        m->comment = std::move(c.text);
      else
        stale(c.line, "CM_", c.key, c.signal);
    } else if (Signal* s = find_sig(c.key, c.signal)) {
      s->comment = std::move(c.text);
    } else {
      stale(c.line, "CM_", c.key, c.signal);
    }
  }
  for (auto& l : long_names_) {
    if (l.signal.empty()) {
      if (Message* m = find(l.key))
        m->long_name = std::move(l.name);
      else
        stale(l.line, "SystemMessageLongSymbol", l.key, l.signal);
    } else if (Signal* s = find_sig(l.key, l.signal)) {
      s->long_name = std::move(l.name);
    } else {
      stale(l.line, "SystemSignalLongSymbol", l.key, l.signal);
    }
  }
  for (auto [key, format] : frame_formats_)
    if (Message* m = find(key)) m->fd = m->fd || format == 14 || format == 15;
  for (const auto& pm : mux_values_)
    if (find(pm.key) == nullptr) stale(pm.line, "SG_MUL_VAL_", pm.key, pm.signal);
  // Vector's placeholder for signals not in any message: never a CAN message.
  std::erase_if(db.messages, [&](const Message& m) {
    if (m.name != kIndependentSignals) return false;
    warn(m.line, "'" + std::string(kIndependentSignals) + "' holds signals of no message: skipped",
         Diagnostic::Severity::Note);
    return true;
  });
  for (Message& m : db.messages) {
    for (Signal& s : m.signals) {
      if (!s.usable) {
        warn(s.line, "signal '" + m.name + "." + s.name + "' left out: " + s.problem);
        continue;
      }
      if (!s.finalize() || s.end_byte() > m.size) {
        s.usable = false;
        s.problem = "start " + std::to_string(s.start_bit) + ", " + std::to_string(s.length) +
                    " bits does not fit the message's " + std::to_string(m.size) + " bytes";
        warn(s.line, "signal '" + m.name + "." + s.name + "' left out: " + s.problem);
      }
    }
    resolve_multiplexing(m);
  }
  if (non_utf8_strings_ > 0)
    warn(first_non_utf8_line_, "text is not UTF-8 (" + std::to_string(non_utf8_strings_) +
                                   " strings from this line on): read as Windows-1252");
  std::stable_sort(
      db.warnings.begin(), db.warnings.end(),
      [](const Diagnostic& a, const Diagnostic& b) { return a.where.line < b.where.line; });
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
      db_.version = text_of(v);
      db_.version_line = t.line;
    } else if (t.text == "NS_") {
      st = expect_punct(':');
      if (st) skip_new_symbols();
    } else if (t.text == "BS_") {
      skip_line(t.line);
    } else if (t.text == "BU_") {
      st = expect_punct(':');
      while (st && lx_.peek().kind == Token::Ident && lx_.peek().line == t.line)
        db_.nodes.emplace_back(lx_.next().text);
    } else if (t.text == "BO_") {
      st = parse_message(t);
    } else if (t.text == "SG_" && discarding_) {
      skip_line(t.line);  // a signal of a message left out
    } else if (t.text == "SG_" && !current_) {
      warn(t.line, "SG_ outside a BO_ message: skipped");
      skip_line(t.line);
    } else if (t.text == "SG_") {
      if (interrupted_)
        warn(t.line, "SG_ line after other statements: read as a signal of message '" +
                         db_.messages[*current_].name + "', the BO_ above");
      interrupted_ = false;
      st = parse_signal(t);
      // An SG_ line that cannot be read, with its error on that line, is
      // skipped: its message keeps the line, and a role in that message is
      // refused (resolve_roles). Any other message stays usable.
      if (!st && current_ && !lx_.lex_error() && st.error().where.line == t.line) {
        Message& m = db_.messages[*current_];
        m.unread.push_back(
            Diagnostic{Diagnostic::Severity::Warning, st.error().where,
                       "SG_ line of message '" + m.name +
                           "' not read, its signal left out: " + st.error().message});
        db_.warnings.push_back(m.unread.back());
        skip_line(t.line);
        st = Status{Ok{}};
      }
    } else if (t.text == "CM_") {
      st = parse_comment();
    } else if (t.text == "VAL_") {
      st = parse_values();
    } else if (t.text == "SIG_VALTYPE_") {
      st = parse_valtype();
    } else if (t.text == "BA_") {
      st = parse_attribute();
    } else if (t.text == "SG_MUL_VAL_") {
      st = parse_mux_values(t);
    } else if (is_keyword(t.text)) {
      current_.reset();
      discarding_ = false;
      skip_statement();
    } else {
      // a keyword of another tool or version: skipped to its ';', or to
      // the next line that begins with a keyword. Between a message's SG_
      // lines it may be a signal mistyped: no role may be in that message.
      const std::string what = "unknown keyword '" + std::string(t.text) + "': skipped";
      warn(t.line, what);
      if (current_)
        db_.messages[*current_].unread.push_back(
            Diagnostic{Diagnostic::Severity::Warning, SourcePos{file_, t.line, t.column}, what});
      skip_unknown(t.line);
      interrupted_ = interrupted_ || current_.has_value() || discarding_;
      continue;
    }
    if (!st) return std::move(st).error();
    // comments, value tables and attributes may sit between a message's
    // SG_ lines (hand-edited files): the SG_ lines after them are still
    // that message's
    const bool between = t.text == "CM_" || t.text == "VAL_" || t.text == "SIG_VALTYPE_" ||
                         t.text == "BA_" || t.text == "SG_MUL_VAL_";
    if (between && (current_ || discarding_)) {
      interrupted_ = true;
    } else if (t.text != "BO_" && t.text != "SG_") {
      current_.reset();
      discarding_ = false;
    }
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
  for (const Signal& s : signals)
    if (!s.long_name.empty() && s.long_name == n) return &s;
  return nullptr;
}

namespace {

/// True when signal `index` of `m` is carried, given the raw value of each
/// multiplexor (`raw_of(j)`): the walk up its multiplexor chain. The
/// parser leaves no loops; `steps` bounds the walk on a hand-made Message.
template <class RawOf>
bool carried(const Message& m, std::size_t index, RawOf&& raw_of) {
  std::size_t i = index;
  for (std::size_t steps = 0; steps <= m.signals.size(); ++steps) {
    const Signal& s = m.signals[i];
    if (!s.usable) return false;
    if (s.mux != MuxRole::Multiplexed) return true;
    if (s.selector < 0 || static_cast<std::size_t>(s.selector) >= m.signals.size()) return false;
    const auto j = static_cast<std::size_t>(s.selector);
    if (!m.signals[j].usable) return false;
    const std::uint64_t v = raw_of(j);
    if (std::none_of(s.selected_by.begin(), s.selected_by.end(),
                     [&](const MuxRange& r) { return v >= r.lo && v <= r.hi; }))
      return false;
    i = j;
  }
  return false;
}

}  // namespace

bool Message::carries(std::size_t index, std::span<const std::uint8_t> payload) const {
  if (index >= signals.size()) return false;
  return carried(*this, index, [&](std::size_t j) { return extract_raw(signals[j], payload); });
}

std::string Diagnostic::describe() const {
  std::string out;
  if (!where.file.empty()) out += where.file + ":";
  if (where.line != 0) out += std::to_string(where.line) + ":";
  if (!out.empty()) out += " ";
  out += severity == Severity::Note ? "note: " : "warning: ";
  return out + text;
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
  for (const Message& m : messages)
    if (!m.long_name.empty() && m.long_name == n) return &m;
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

FrameCodec::FrameCodec(const Database& db) : db_(&db), standard_(kStdIdMask + 1, -1) {
  index_.reserve(db.messages.size() * 2);
  plans_.resize(db.messages.size());
  for (std::size_t i = 0; i < db.messages.size(); ++i) {
    const Message& m = db.messages[i];
    const auto at = static_cast<std::int32_t>(i);
    index_[m.id | (m.extended ? kDbcExtendedFlag : 0u)] = static_cast<std::uint32_t>(i);
    if (!m.extended && m.id <= kStdIdMask) standard_[m.id] = at;  // the last of an ID, as above
    Plan& p = plans_[i];
    p.first = static_cast<std::uint32_t>(slots_.size());
    p.count = static_cast<std::uint32_t>(m.signals.size());
    max_signals_ = std::max(max_signals_, m.signals.size());
    p.plain = true;
    for (const Signal& sig : m.signals) {
      p.plain = p.plain && sig.usable && sig.mux != MuxRole::Multiplexed;
      Slot sl{};
      sl.signal = &sig;
      sl.mask = low_mask(sig.length);
      sl.little_endian = sig.order == ByteOrder::LittleEndian;
      sl.integer = sig.type == ValueType::Integer;
      sl.unsigned64 = !sig.is_signed && sig.length >= 64;
      sl.sign = sig.is_signed && sig.length >= 1 && sig.length < 64
                    ? std::uint64_t{1} << (sig.length - 1)
                    : 0;
      sl.factor = sig.factor;
      sl.offset = sig.offset;
      // one load of 8 bytes from first_byte holds the signal's bytes, and
      // stays inside the frame's data (whatever lies past the signal's
      // bytes is shifted or masked off)
      sl.direct = sig.usable && sig.span >= 1 && sig.span <= 8 && sig.first_byte + 8 <= kMaxFdLen;
      sl.drop = sl.direct ? 64 - 8 * sig.span : 0;
      slots_.push_back(sl);
    }
  }
}

std::int32_t FrameCodec::index_of(const Frame& f) const {
  if (!f.extended && f.id <= kStdIdMask) return standard_[f.id];
  const auto it = index_.find(f.id | (f.extended ? kDbcExtendedFlag : 0u));
  return it == index_.end() ? -1 : static_cast<std::int32_t>(it->second);
}

const Message* FrameCodec::message_for(const Frame& f) const {
  const std::int32_t k = index_of(f);
  return k < 0 ? nullptr : &db_->messages[static_cast<std::size_t>(k)];
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
  const Message* found = nullptr;
  if (const DecodeStatus st = check(f, &found); st != DecodeStatus::Ok) return st;
  const Message& m = *found;
  if (msg != nullptr) *msg = found;
  const Plan& plan = plans_[static_cast<std::size_t>(found - db_->messages.data())];
  const std::span<const std::uint8_t> payload(f.data.data(), f.len);
  const std::size_t n = std::min<std::size_t>(plan.count, out.size());
  for (std::size_t i = 0; i < n; ++i) {
    const Slot& sl = slots_[plan.first + i];
    if (!plan.plain && !m.carries(i, payload)) {
      out[i] = std::numeric_limits<double>::quiet_NaN();
      continue;
    }
    std::uint64_t raw = 0;
    if (sl.direct) {
      std::uint64_t w = 0;
      std::memcpy(&w, f.data.data() + sl.signal->first_byte, sizeof w);
      if constexpr (std::endian::native == std::endian::big) w = __builtin_bswap64(w);
      // little endian now: a Motorola signal's first byte is its top
      if (!sl.little_endian) w = __builtin_bswap64(w) >> sl.drop;
      raw = (w >> sl.signal->shift) & sl.mask;
    } else {
      raw = extract_raw(*sl.signal, payload);
    }
    if (!sl.integer) {
      out[i] = raw_to_physical(*sl.signal, raw);
      continue;
    }
    // raw_to_physical of an integer signal, from the slot: sign-extended
    // by (raw ^ sign) - sign (raw has no bits above the signal's), and
    // converted from int64, which holds the same integer (so the same
    // double) and converts in one instruction where uint64 takes several
    const double base =
        sl.unsigned64 ? static_cast<double>(raw)
                      : static_cast<double>(static_cast<std::int64_t>((raw ^ sl.sign) - sl.sign));
    out[i] = base * sl.factor + sl.offset;
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
  // the raw value of each multiplexor (a NaN one's bits stay 0)
  std::vector<std::uint64_t> mux_raw(msg.signals.size(), 0);
  for (std::size_t i = 0; i < msg.signals.size() && i < values.size(); ++i)
    if (msg.signals[i].is_multiplexor() && msg.signals[i].usable && !std::isnan(values[i]))
      mux_raw[i] = to_raw(msg.signals[i], values[i]).raw;
  for (std::size_t i = 0; i < msg.signals.size() && i < values.size(); ++i) {
    const Signal& s = msg.signals[i];
    if (std::isnan(values[i]) || !s.usable) continue;
    if (!carried(msg, i, [&](std::size_t j) { return mux_raw[j]; })) continue;
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
