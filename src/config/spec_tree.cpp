#include "config/spec_tree.hpp"

#include <charconv>
#include <cmath>
#include <limits>
#include <new>
#include <unordered_set>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <yaml-cpp/depthguard.h>
#include <yaml-cpp/yaml.h>

namespace ecat::config::detail {

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

// ---- YAML -------------------------------------------------------------------------------------

namespace {

constexpr std::size_t kMaxYamlNodes = 200'000;  // after alias expansion: stops "billion laughs"
constexpr int kMaxYamlDepth = 48;

class YamlConverter {
 public:
  explicit YamlConverter(const SpecContext& context) : context_(context) {}

  Result<SpecNode> convert(const YAML::Node& node, int depth, int parent_line) {
    if (++nodes_ > kMaxYamlNodes) {
      return Error(Errc::out_of_range, fmt::format("{}: more than {} YAML nodes (aliases included)",
                                                   context_.source, kMaxYamlNodes));
    }
    SpecNode out;
    const YAML::Mark mark = node.Mark();
    out.line = mark.is_null() ? parent_line : mark.line + 1;
    if (depth > kMaxYamlDepth) {
      return spec_error(context_, out, "",
                        fmt::format("nested deeper than {} levels", kMaxYamlDepth));
    }
    switch (node.Type()) {
      case YAML::NodeType::Undefined:
      case YAML::NodeType::Null:
        out.type = SpecNode::Type::null;
        return out;
      case YAML::NodeType::Scalar:
        out.type = SpecNode::Type::scalar;
        out.text = node.Scalar();
        out.quoted = node.Tag() == "!";
        return out;
      case YAML::NodeType::Sequence:
        out.type = SpecNode::Type::sequence;
        for (const auto& item : node) {
          auto child = convert(item, depth + 1, out.line);
          if (!child) return child;
          out.items.push_back(std::move(*child));
        }
        return out;
      case YAML::NodeType::Map:
        out.type = SpecNode::Type::mapping;
        for (const auto& entry : node) {
          if (!entry.first.IsScalar()) {
            SpecNode where;
            where.line = entry.first.Mark().is_null() ? out.line : entry.first.Mark().line + 1;
            return spec_error(context_, where, "", "a key must be a plain scalar");
          }
          std::string key = entry.first.Scalar();
          auto child = convert(entry.second, depth + 1, out.line);
          if (!child) return child;
          if (out.find(key) != nullptr) {
            return spec_error(context_, *child, key, "duplicate key");
          }
          out.entries.emplace_back(std::move(key), std::move(*child));
        }
        return out;
    }
    return out;
  }

 private:
  const SpecContext& context_;
  std::size_t nodes_ = 0;
};

}  // namespace

Result<SpecNode> parse_yaml(std::string_view text, const SpecContext& context) {
  try {
    const YAML::Node root = YAML::Load(std::string(text));
    YamlConverter converter(context);
    return converter.convert(root, 0, 0);
  } catch (const YAML::DeepRecursion& e) {
    // yaml-cpp's own guard, hit before ours can count (its message is only "bad file").
    SpecNode where;
    where.line = e.mark.is_null() ? 0 : e.mark.line + 1;
    return spec_error(context, where, "",
                      fmt::format("nested deeper than {} levels", kMaxYamlDepth), Errc::malformed);
  } catch (const YAML::Exception& e) {
    SpecNode where;
    where.line = e.mark.is_null() ? 0 : e.mark.line + 1;
    return spec_error(context, where, "", fmt::format("YAML syntax error: {}", e.msg),
                      Errc::malformed);
  } catch (const std::exception& e) {
    return Error(Errc::malformed,
                 fmt::format("{}: cannot read YAML: {}", context.source, e.what()));
  }
}

// ---- JSON -------------------------------------------------------------------------------------

namespace {

// Builds the tree from nlohmann's SAX events. SAX rather than nlohmann's own document: its parser
// keeps the nesting on a heap stack (no recursion), so the depth bound below is checked before
// anything deep exists, and numbers arrive with their text as written (1e99 stays 1e99, not a
// rounded double that to_int could not tell from an integer).
class JsonTreeBuilder final : public nlohmann::json_sax<nlohmann::json> {
 public:
  static constexpr std::size_t kMaxReason = 200;
  static constexpr std::size_t kMaxKeyShown = 64;

  explicit JsonTreeBuilder(std::size_t max_depth) : max_depth_(max_depth) {}

  bool null() override {
    ++events_;
    return add(SpecNode{}) != nullptr;
  }
  bool boolean(bool value) override {
    ++events_;
    return add_scalar(value ? "true" : "false", false);
  }
  bool number_integer(number_integer_t value) override {
    ++events_;
    return add_scalar(std::to_string(value), false);
  }
  bool number_unsigned(number_unsigned_t value) override {
    ++events_;
    return add_scalar(std::to_string(value), false);
  }
  bool number_float(number_float_t /*value*/, const string_t& text) override {
    ++events_;
    return add_scalar(text, false);
  }
  bool string(string_t& value) override {
    ++events_;
    return add_scalar(std::move(value), true);
  }
  bool binary(binary_t& /*value*/) override {
    ++events_;
    return refuse("binary values are not JSON");  // only reachable from CBOR and friends
  }
  bool start_object(std::size_t /*elements*/) override {
    ++events_;
    return open(SpecNode::Type::mapping);
  }
  bool key(string_t& key) override {
    ++events_;
    Frame& frame = open_.back();
    if (!frame.keys.insert(key).second) {
      // A key can be as long as the request: the start names it well enough.
      const bool long_key = key.size() > kMaxKeyShown;
      return refuse(
          fmt::format("duplicate key '{}{}'", key.substr(0, kMaxKeyShown), long_key ? "..." : ""));
    }
    pending_key_ = std::move(key);
    return true;
  }
  bool end_object() override {
    ++events_;
    return close();
  }
  bool start_array(std::size_t /*elements*/) override {
    ++events_;
    return open(SpecNode::Type::sequence);
  }
  bool end_array() override {
    ++events_;
    return close();
  }
  bool parse_error(std::size_t position, const std::string& /*last_token*/,
                   const nlohmann::json::exception& ex) override {
    // nlohmann counts from 1 to the last byte it read: the byte that made the text invalid (or
    // one past the end when the text stopped short).
    error_at_ = position > 0 ? position - 1 : 0;
    error_ = nlohmann_reason(ex.what());
    // "last read: '...'" quotes the whole token, which for an unterminated string is the rest of
    // the request: the start says enough.
    if (error_.size() > kMaxReason) error_ = error_.substr(0, kMaxReason) + "...";
    return false;
  }

  // Why the parse stopped (after sax_parse returned false): "at byte N: ...".
  Error failure(std::string_view text) const {
    const std::size_t at = refused_ ? token_offset(text, events_ - 1) : error_at_;
    return Error(Errc::malformed, fmt::format("invalid JSON at byte {}{}: {}", at,
                                              at >= text.size() ? " (the end)" : "", error_));
  }

  SpecNode take() { return std::move(root_); }

 private:
  struct Frame {
    SpecNode* node;
    std::unordered_set<std::string> keys;  // an object's keys so far (duplicates are refused)
  };

  // Adds a value where the parser is (the root, the open list, or the open object's pending key);
  // the returned node stays put while it is open, because its parent only grows after it closes.
  SpecNode* add(SpecNode value) {
    value.line = 1;  // JSON requests are one line
    if (open_.empty()) {
      root_ = std::move(value);
      return &root_;
    }
    SpecNode& parent = *open_.back().node;
    if (parent.is_sequence()) {
      parent.items.push_back(std::move(value));
      return &parent.items.back();
    }
    parent.entries.emplace_back(std::move(pending_key_), std::move(value));
    return &parent.entries.back().value;
  }

  bool add_scalar(std::string text, bool quoted) {
    SpecNode node;
    node.type = SpecNode::Type::scalar;
    node.text = std::move(text);
    node.quoted = quoted;
    return add(std::move(node)) != nullptr;
  }

  bool open(SpecNode::Type type) {
    if (open_.size() >= max_depth_) {
      return refuse(fmt::format("nested deeper than {} levels", max_depth_));
    }
    SpecNode node;
    node.type = type;
    open_.push_back(Frame{add(std::move(node)), {}});
    return true;
  }

  bool close() {
    open_.pop_back();
    return true;
  }

  // Stops the parse at the current event (a rule of ours, not JSON syntax, was broken).
  bool refuse(std::string why) {
    error_ = std::move(why);
    refused_ = true;
    return false;
  }

  // The byte where the `index`-th SAX event's token starts. The events carry no position, but each
  // one is exactly one token of the text (a bracket, a key, a value; ',' and ':' are none), and the
  // text up to a refused event was valid, so counting tokens finds it. Only run on that failure.
  static std::size_t token_offset(std::string_view text, std::size_t index) {
    std::size_t count = 0;
    std::size_t i = 0;
    while (i < text.size()) {
      const char c = text[i];
      if (c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == ',' || c == ':') {
        ++i;
        continue;
      }
      if (count++ == index) return i;
      if (c == '"') {
        for (++i; i < text.size() && text[i] != '"'; ++i) {
          if (text[i] == '\\') ++i;
        }
        ++i;
      } else if (c == '[' || c == ']' || c == '{' || c == '}') {
        ++i;
      } else {
        while (i < text.size() &&
               std::string_view(" \t\n\r,:[]{}\"").find(text[i]) == std::string_view::npos) {
          ++i;
        }
      }
    }
    return text.size();
  }

  // "[json.exception.parse_error.101] parse error at line 1, column 2: syntax error while parsing
  // value - invalid literal; last read: 'no'" -> "syntax error while parsing value - ...": the
  // position is given as a byte offset already, and the exception id means nothing to a user.
  static std::string nlohmann_reason(std::string_view what) {
    if (what.rfind("[json.exception.", 0) == 0) {
      if (const auto end = what.find("] "); end != std::string_view::npos) {
        what.remove_prefix(end + 2);
      }
    }
    if (what.rfind("parse error", 0) == 0) {
      if (const auto colon = what.find(": "); colon != std::string_view::npos) {
        what.remove_prefix(colon + 2);
      }
    }
    return std::string(what);
  }

  std::size_t max_depth_;
  SpecNode root_;
  std::vector<Frame> open_;
  std::string pending_key_;
  std::string error_ = "unexpected input";
  std::size_t error_at_ = 0;
  std::size_t events_ = 0;
  bool refused_ = false;
};

template <class Json>
std::string dump_replacing(const Json& value, int indent) {
  try {
    return value.dump(indent, ' ', false, nlohmann::json::error_handler_t::replace);
  } catch (const std::exception& e) {
    // Unreachable with the replace handler (the only throwing case is invalid UTF-8); still no
    // exception leaves: the reply says what happened, as JSON.
    return nlohmann::json{{"ok", false}, {"error", std::string("internal: ") + e.what()}}.dump(
        -1, ' ', false, nlohmann::json::error_handler_t::replace);
  }
}

}  // namespace

Result<SpecNode> parse_json(std::string_view text, std::size_t max_depth) {
  JsonTreeBuilder builder(max_depth);
  try {
    if (!nlohmann::json::sax_parse(text.begin(), text.end(), &builder)) {
      return builder.failure(text);
    }
  } catch (const nlohmann::json::exception& e) {
    return Error(Errc::malformed, fmt::format("invalid JSON: {}", e.what()));
  } catch (const std::bad_alloc&) {
    return Error(Errc::out_of_range, "invalid JSON: too large to hold in memory");
  }
  return builder.take();
}

std::string dump_json(const nlohmann::json& value, int indent) {
  return dump_replacing(value, indent);
}

std::string dump_json(const nlohmann::ordered_json& value, int indent) {
  return dump_replacing(value, indent);
}

void append_json_string(std::string& out, std::string_view text) {
  out += dump_json(nlohmann::json(std::string(text)));
}

std::string json_string(std::string_view text) {
  return dump_json(nlohmann::json(std::string(text)));
}

}  // namespace ecat::config::detail
