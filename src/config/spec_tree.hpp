// A small document tree shared by ring files (YAML: the simulator's sections and the master's),
// and the simulator's control requests (JSON), so that all of them report errors the same way:
// "ring.yaml:12: slaves[3].port: ..." for files, "fault.slave: ..." for one-line requests.
//
// It lives in the config layer because both the master (src/master/config_yaml.cpp) and the
// simulator (src/sim) read it, and neither may include the other. Private to the library: the
// public API never exposes yaml-cpp, nlohmann-json or this tree.
#pragma once

#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include <ecat/result.hpp>

namespace ecat::config::detail {

struct SpecEntry;

struct SpecNode {
  enum class Type : std::uint8_t { null, scalar, sequence, mapping };

  Type type = Type::null;
  std::string text;     // scalar: as written (numbers too)
  bool quoted = false;  // scalar written as a quoted string
  std::vector<SpecNode> items;
  std::vector<SpecEntry> entries;  // mapping, in document order
  int line = 0;                    // 1-based; 0 = unknown

  bool is_null() const noexcept { return type == Type::null; }
  bool is_scalar() const noexcept { return type == Type::scalar; }
  bool is_sequence() const noexcept { return type == Type::sequence; }
  bool is_mapping() const noexcept { return type == Type::mapping; }
  const SpecNode* find(std::string_view key) const noexcept;
};

// One key of a mapping. (Not std::pair: a pair cannot hold the still incomplete SpecNode.)
struct SpecEntry {
  SpecEntry(std::string k, SpecNode v) : key(std::move(k)), value(std::move(v)) {}
  std::string key;
  SpecNode value;
};

std::string_view type_name(const SpecNode& node) noexcept;

// Where a document came from, for messages: `source` is the file name ("ring.yaml"), or empty for
// a control request (which is one line: no line numbers either).
struct SpecContext {
  std::string source;
};

// "ring.yaml:12: slaves[3].profile: unknown profile" / "fault.kind: unknown fault kind".
Error spec_error(const SpecContext& context, const SpecNode& node, std::string_view path,
                 std::string_view message, Errc code = Errc::invalid_argument);

// Reads a mapping strictly: every key must be one of `known` (else "unknown key").
Result<void> check_keys(const SpecContext& context, const SpecNode& node, std::string_view path,
                        std::initializer_list<std::string_view> known);
Result<const SpecNode*> require(const SpecContext& context, const SpecNode& node,
                                std::string_view path, std::string_view key);

// Scalar conversions. Integers accept decimal, 0x hex and a leading minus; the range is checked.
Result<std::int64_t> to_int(const SpecContext& context, const SpecNode& node, std::string_view path,
                            std::int64_t min, std::int64_t max);
Result<double> to_double(const SpecContext& context, const SpecNode& node, std::string_view path);
Result<bool> to_bool(const SpecContext& context, const SpecNode& node, std::string_view path);
Result<std::string> to_text(const SpecContext& context, const SpecNode& node,
                            std::string_view path);

std::string join_path(std::string_view path, std::string_view key);
std::string index_path(std::string_view path, std::size_t index);

// Parses YAML (yaml-cpp) into the tree, bounding size, depth and alias expansion; syntax errors
// carry the line.
Result<SpecNode> parse_yaml(std::string_view text, const SpecContext& context);

// Parses one JSON value (RFC 8259, by nlohmann-json; the whole text must be one value with
// optional whitespace). Nesting deeper than `max_depth` containers and duplicate keys are refused;
// errors say "invalid JSON at byte N: ..." (N counted from 0). Integers keep their digits and
// fractions their text as written, so to_int/to_double tell them apart.
Result<SpecNode> parse_json(std::string_view text, std::size_t max_depth = 32);

// JSON text of `value`, compact (indent < 0) or pretty. Never throws: strings that are not valid
// UTF-8 (names from files, echoed input) have each bad sequence replaced by U+FFFD instead of
// making the whole reply unparsable.
std::string dump_json(const nlohmann::json& value, int indent = -1);
std::string dump_json(const nlohmann::ordered_json& value, int indent = -1);

// Writes `text` as a JSON string literal (with quotes), as dump_json does.
void append_json_string(std::string& out, std::string_view text);
std::string json_string(std::string_view text);

}  // namespace ecat::config::detail
