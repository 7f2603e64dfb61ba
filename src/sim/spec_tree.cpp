#include "sim/spec_tree.hpp"

#include <charconv>
#include <cmath>
#include <limits>

#include <fmt/format.h>

namespace ecat::sim::detail {

const SpecNode* SpecNode::find(std::string_view key) const noexcept {
  for (const auto& [k, v] : entries) {
    if (k == key) return &v;
  }
  return nullptr;
}

std::string_view type_name(const SpecNode& node) noexcept {
  switch (node.type) {
    case SpecNode::Type::null:
      return "nothing";
    case SpecNode::Type::scalar:
      return "a scalar";
    case SpecNode::Type::sequence:
      return "a list";
    case SpecNode::Type::mapping:
      return "a mapping";
  }
  return "?";
}

Error spec_error(const SpecContext& context, const SpecNode& node, std::string_view path,
                 std::string_view message, Errc code) {
  std::string text;
  if (!context.source.empty()) {
    text = node.line > 0 ? fmt::format("{}:{}: ", context.source, node.line)
                         : fmt::format("{}: ", context.source);
  }
  if (!path.empty()) text += fmt::format("{}: ", path);
  text += message;
  return Error(code, std::move(text));
}

std::string join_path(std::string_view path, std::string_view key) {
  if (path.empty()) return std::string(key);
  return fmt::format("{}.{}", path, key);
}

std::string index_path(std::string_view path, std::size_t index) {
  return fmt::format("{}[{}]", path, index);
}

Result<void> check_keys(const SpecContext& context, const SpecNode& node, std::string_view path,
                        std::initializer_list<std::string_view> known) {
  if (!node.is_mapping()) {
    return spec_error(context, node, path,
                      fmt::format("expected a mapping, found {}", type_name(node)));
  }
  for (const auto& [key, value] : node.entries) {
    bool ok = false;
    for (auto k : known)
      ok = ok || k == key;
    if (!ok) {
      std::string list;
      for (auto k : known)
        list += (list.empty() ? "" : ", ") + std::string(k);
      return spec_error(context, value, join_path(path, key),
                        fmt::format("unknown key (known: {})", list));
    }
  }
  return ok();
}

Result<const SpecNode*> require(const SpecContext& context, const SpecNode& node,
                                std::string_view path, std::string_view key) {
  const SpecNode* found = node.find(key);
  if (found == nullptr) {
    return spec_error(context, node, path, fmt::format("missing key '{}'", key));
  }
  return found;
}

namespace {

std::optional<std::int64_t> parse_integer(std::string_view text) {
  bool negative = false;
  if (!text.empty() && text.front() == '-') {
    negative = true;
    text.remove_prefix(1);
  } else if (!text.empty() && text.front() == '+') {
    text.remove_prefix(1);
  }
  int base = 10;
  if (text.size() > 2 && text[0] == '0' && (text[1] == 'x' || text[1] == 'X')) {
    base = 16;
    text.remove_prefix(2);
  }
  if (text.empty()) return std::nullopt;
  std::uint64_t magnitude = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), magnitude, base);
  if (ec != std::errc() || end != text.data() + text.size()) return std::nullopt;
  constexpr auto kMax = static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max());
  if (negative) {
    if (magnitude > kMax + 1) return std::nullopt;
    return magnitude == kMax + 1 ? std::numeric_limits<std::int64_t>::min()
                                 : -static_cast<std::int64_t>(magnitude);
  }
  if (magnitude > kMax) return std::nullopt;
  return static_cast<std::int64_t>(magnitude);
}

}  // namespace

Result<std::int64_t> to_int(const SpecContext& context, const SpecNode& node, std::string_view path,
                            std::int64_t min, std::int64_t max) {
  if (!node.is_scalar()) {
    return spec_error(context, node, path,
                      fmt::format("expected an integer, found {}", type_name(node)));
  }
  const auto value = parse_integer(node.text);
  if (!value) {
    return spec_error(context, node, path,
                      fmt::format("'{}' is not an integer (decimal or 0x hex)", node.text));
  }
  if (*value < min || *value > max) {
    return spec_error(context, node, path,
                      fmt::format("{} is out of range ({} to {})", node.text, min, max),
                      Errc::out_of_range);
  }
  return *value;
}

Result<double> to_double(const SpecContext& context, const SpecNode& node, std::string_view path) {
  if (!node.is_scalar()) {
    return spec_error(context, node, path,
                      fmt::format("expected a number, found {}", type_name(node)));
  }
  if (const auto integer = parse_integer(node.text)) return static_cast<double>(*integer);
  std::string_view text = node.text;
  if (!text.empty() && text.front() == '+') text.remove_prefix(1);
  double value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (text.empty() || ec != std::errc() || end != text.data() + text.size() ||
      !std::isfinite(value)) {
    return spec_error(context, node, path, fmt::format("'{}' is not a number", node.text));
  }
  return value;
}

Result<bool> to_bool(const SpecContext& context, const SpecNode& node, std::string_view path) {
  if (node.is_scalar() && !node.quoted) {
    if (node.text == "true") return true;
    if (node.text == "false") return false;
  }
  return spec_error(
      context, node, path,
      fmt::format("expected true or false, found {}",
                  node.is_scalar() ? "'" + node.text + "'" : std::string(type_name(node))));
}

Result<std::string> to_text(const SpecContext& context, const SpecNode& node,
                            std::string_view path) {
  if (!node.is_scalar()) {
    return spec_error(context, node, path,
                      fmt::format("expected a string, found {}", type_name(node)));
  }
  return node.text;
}

// ---- JSON ----------------------------------------------------------------------------------

namespace {

class JsonParser {
 public:
  JsonParser(std::string_view text, std::size_t max_depth) : text_(text), max_depth_(max_depth) {}

  Result<SpecNode> parse_document() {
    skip_space();
    SpecNode root;
    if (auto r = parse_value(root, 0); !r) return std::move(r).error();
    skip_space();
    if (pos_ != text_.size()) return fail("unexpected text after the JSON value");
    return root;
  }

 private:
  Error fail(std::string_view what) const {
    return Error(Errc::malformed, fmt::format("invalid JSON at byte {}: {}", pos_, what));
  }

  void skip_space() {
    while (pos_ < text_.size() && (text_[pos_] == ' ' || text_[pos_] == '\t' ||
                                   text_[pos_] == '\n' || text_[pos_] == '\r')) {
      ++pos_;
    }
  }

  bool consume(std::string_view literal) {
    if (text_.substr(pos_, literal.size()) != literal) return false;
    pos_ += literal.size();
    return true;
  }

  Result<void> parse_value(SpecNode& out, std::size_t depth) {
    if (depth > max_depth_) return fail(fmt::format("nested deeper than {} levels", max_depth_));
    out.line = 1;
    if (pos_ >= text_.size()) return fail("expected a value, found the end");
    const char c = text_[pos_];
    if (c == '{') return parse_object(out, depth);
    if (c == '[') return parse_array(out, depth);
    if (c == '"') {
      out.type = SpecNode::Type::scalar;
      out.quoted = true;
      return parse_string(out.text);
    }
    if (consume("true")) {
      out.type = SpecNode::Type::scalar;
      out.text = "true";
      return ok();
    }
    if (consume("false")) {
      out.type = SpecNode::Type::scalar;
      out.text = "false";
      return ok();
    }
    if (consume("null")) {
      out.type = SpecNode::Type::null;
      return ok();
    }
    if (c == '-' || (c >= '0' && c <= '9')) return parse_number(out);
    return fail(fmt::format("unexpected character '{}'", printable(c)));
  }

  static std::string printable(char c) {
    const auto u = static_cast<unsigned char>(c);
    if (u >= 0x20 && u < 0x7F) return std::string(1, c);
    return fmt::format("\\x{:02x}", u);
  }

  Result<void> parse_number(SpecNode& out) {
    const std::size_t start = pos_;
    auto digits = [&] {
      const std::size_t from = pos_;
      while (pos_ < text_.size() && text_[pos_] >= '0' && text_[pos_] <= '9')
        ++pos_;
      return pos_ > from;
    };
    if (text_[pos_] == '-') ++pos_;
    if (pos_ < text_.size() && text_[pos_] == '0') {
      ++pos_;
    } else if (!digits()) {
      return fail("a number needs digits");
    }
    if (pos_ < text_.size() && text_[pos_] == '.') {
      ++pos_;
      if (!digits()) return fail("a fraction needs digits");
    }
    if (pos_ < text_.size() && (text_[pos_] == 'e' || text_[pos_] == 'E')) {
      ++pos_;
      if (pos_ < text_.size() && (text_[pos_] == '+' || text_[pos_] == '-')) ++pos_;
      if (!digits()) return fail("an exponent needs digits");
    }
    out.type = SpecNode::Type::scalar;
    out.text = std::string(text_.substr(start, pos_ - start));
    return ok();
  }

  Result<unsigned> hex4() {
    if (pos_ + 4 > text_.size()) return fail("\\u needs 4 hex digits");
    unsigned value = 0;
    for (int i = 0; i < 4; ++i) {
      const char c = text_[pos_++];
      value <<= 4;
      if (c >= '0' && c <= '9') {
        value |= static_cast<unsigned>(c - '0');
      } else if (c >= 'a' && c <= 'f') {
        value |= static_cast<unsigned>(c - 'a' + 10);
      } else if (c >= 'A' && c <= 'F') {
        value |= static_cast<unsigned>(c - 'A' + 10);
      } else {
        return fail("\\u needs 4 hex digits");
      }
    }
    return value;
  }

  static void append_utf8(std::string& out, unsigned cp) {
    if (cp < 0x80) {
      out += static_cast<char>(cp);
    } else if (cp < 0x800) {
      out += static_cast<char>(0xC0 | (cp >> 6));
      out += static_cast<char>(0x80 | (cp & 0x3F));
    } else if (cp < 0x10000) {
      out += static_cast<char>(0xE0 | (cp >> 12));
      out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
      out += static_cast<char>(0x80 | (cp & 0x3F));
    } else {
      out += static_cast<char>(0xF0 | (cp >> 18));
      out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
      out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
      out += static_cast<char>(0x80 | (cp & 0x3F));
    }
  }

  Result<void> parse_string(std::string& out) {
    ++pos_;  // opening quote
    while (true) {
      if (pos_ >= text_.size()) return fail("unterminated string");
      const char c = text_[pos_++];
      if (c == '"') return ok();
      if (static_cast<unsigned char>(c) < 0x20) return fail("control character in a string");
      if (c != '\\') {
        out += c;
        continue;
      }
      if (pos_ >= text_.size()) return fail("unterminated escape");
      const char e = text_[pos_++];
      switch (e) {
        case '"':
        case '\\':
        case '/':
          out += e;
          break;
        case 'b':
          out += '\b';
          break;
        case 'f':
          out += '\f';
          break;
        case 'n':
          out += '\n';
          break;
        case 'r':
          out += '\r';
          break;
        case 't':
          out += '\t';
          break;
        case 'u': {
          auto first = hex4();
          if (!first) return std::move(first).error();
          unsigned cp = *first;
          if (cp >= 0xD800 && cp <= 0xDBFF) {
            if (!consume("\\u")) return fail("a high surrogate needs a low surrogate");
            auto second = hex4();
            if (!second) return std::move(second).error();
            if (*second < 0xDC00 || *second > 0xDFFF) return fail("invalid low surrogate");
            cp = 0x10000 + ((cp - 0xD800) << 10) + (*second - 0xDC00);
          } else if (cp >= 0xDC00 && cp <= 0xDFFF) {
            return fail("a low surrogate without a high one");
          }
          append_utf8(out, cp);
          break;
        }
        default:
          return fail(fmt::format("unknown escape '\\{}'", printable(e)));
      }
    }
  }

  Result<void> parse_array(SpecNode& out, std::size_t depth) {
    out.type = SpecNode::Type::sequence;
    ++pos_;
    skip_space();
    if (pos_ < text_.size() && text_[pos_] == ']') {
      ++pos_;
      return ok();
    }
    while (true) {
      skip_space();
      out.items.emplace_back();
      if (auto r = parse_value(out.items.back(), depth + 1); !r) return r;
      skip_space();
      if (pos_ >= text_.size()) return fail("unterminated list");
      const char c = text_[pos_++];
      if (c == ']') return ok();
      if (c != ',') return fail("expected ',' or ']'");
    }
  }

  Result<void> parse_object(SpecNode& out, std::size_t depth) {
    out.type = SpecNode::Type::mapping;
    ++pos_;
    skip_space();
    if (pos_ < text_.size() && text_[pos_] == '}') {
      ++pos_;
      return ok();
    }
    while (true) {
      skip_space();
      if (pos_ >= text_.size() || text_[pos_] != '"') return fail("expected a key string");
      std::string key;
      if (auto r = parse_string(key); !r) return r;
      if (out.find(key) != nullptr) return fail(fmt::format("duplicate key '{}'", key));
      skip_space();
      if (pos_ >= text_.size() || text_[pos_] != ':') return fail("expected ':' after a key");
      ++pos_;
      skip_space();
      SpecNode value;
      if (auto r = parse_value(value, depth + 1); !r) return r;
      out.entries.emplace_back(std::move(key), std::move(value));
      skip_space();
      if (pos_ >= text_.size()) return fail("unterminated object");
      const char c = text_[pos_++];
      if (c == '}') return ok();
      if (c != ',') return fail("expected ',' or '}'");
    }
  }

  std::string_view text_;
  std::size_t max_depth_;
  std::size_t pos_ = 0;
};

// Length of the valid UTF-8 sequence starting at s[i], or 0.
std::size_t utf8_length(std::string_view s, std::size_t i) {
  const auto b0 = static_cast<unsigned char>(s[i]);
  std::size_t n = 0;
  unsigned min = 0;
  if (b0 >= 0xC2 && b0 <= 0xDF) {
    n = 2;
    min = 0x80;
  } else if (b0 >= 0xE0 && b0 <= 0xEF) {
    n = 3;
    min = 0x800;
  } else if (b0 >= 0xF0 && b0 <= 0xF4) {
    n = 4;
    min = 0x10000;
  } else {
    return 0;
  }
  if (i + n > s.size()) return 0;
  unsigned cp = b0 & (0x7F >> n);
  for (std::size_t k = 1; k < n; ++k) {
    const auto b = static_cast<unsigned char>(s[i + k]);
    if ((b & 0xC0) != 0x80) return 0;
    cp = (cp << 6) | (b & 0x3F);
  }
  if (cp < min || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return 0;
  return n;
}

}  // namespace

Result<SpecNode> parse_json(std::string_view text, std::size_t max_depth) {
  return JsonParser(text, max_depth).parse_document();
}

void append_json_string(std::string& out, std::string_view text) {
  out += '"';
  for (std::size_t i = 0; i < text.size();) {
    const auto c = static_cast<unsigned char>(text[i]);
    if (c >= 0x80) {
      // Invalid UTF-8 would make the whole reply unparsable for strict clients.
      const std::size_t n = utf8_length(text, i);
      if (n == 0) {
        out += "\\ufffd";
        ++i;
      } else {
        out.append(text.substr(i, n));
        i += n;
      }
      continue;
    }
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\r':
        out += "\\r";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        if (c < 0x20 || c == 0x7F) {
          out += fmt::format("\\u{:04x}", c);
        } else {
          out += static_cast<char>(c);
        }
    }
    ++i;
  }
  out += '"';
}

std::string json_string(std::string_view text) {
  std::string out;
  append_json_string(out, text);
  return out;
}

}  // namespace ecat::sim::detail
