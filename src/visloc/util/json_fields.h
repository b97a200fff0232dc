// Typed reading of the JSON our files hold (manifest.json, a segment's META
// and IMAGES), with errors that name the file and the field: a value of the
// wrong type, a missing field, a number that is not finite or does not fit
// is an Error(kFormat) "FILE: field 'a.b[3].c' must be ..., found ...", never
// a nlohmann exception or a silent conversion (1.5 → 1, 1e300 → garbage,
// null → an empty list).
#pragma once

#include <cstdint>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "visloc/util/error.h"

namespace visloc {

class JsonField {
 public:
  // `file` names the file for messages; `path` is this value's field path.
  JsonField(const nlohmann::json& value, std::string file, std::string path = "")
      : value_(&value), file_(std::move(file)), path_(std::move(path)) {}

  const nlohmann::json& json() const { return *value_; }
  const std::string& field_path() const { return path_; }
  const std::string& file() const { return file_; }

  // Object members. `has` is false for a missing member and for null.
  bool has(std::string_view key) const;
  JsonField at(std::string_view key) const;  // must be present (and not null)
  // Array elements; size() requires an array.
  size_t size() const;
  JsonField at(size_t index) const;

  std::string string() const;
  bool boolean() const;
  double number() const;  // any finite JSON number
  // An integer (JSON integer syntax) within [lo, hi].
  int64_t integer(int64_t lo, int64_t hi) const;
  uint64_t unsigned_integer(uint64_t hi = std::numeric_limits<uint64_t>::max()) const;
  // An array of finite numbers; `expected_size` (if not npos) must match.
  std::vector<double> numbers(size_t expected_size = std::string::npos) const;
  std::vector<std::string> strings() const;

  // Convenience for members with defaults.
  std::string string_or(std::string_view key, std::string fallback) const {
    return has(key) ? at(key).string() : fallback;
  }

  template <typename... Parts>
  [[noreturn]] void fail(const Parts&... parts) const {
    throw_error(ErrorCode::kFormat, file_, ": field '", path_.empty() ? std::string("(top level)") : path_, "' ",
                parts...);
  }

 private:
  std::string type_name() const;
  void require(bool ok, std::string_view expected) const;

  const nlohmann::json* value_;
  std::string file_;
  std::string path_;
};

// Parses `text` as JSON; a syntax error is Error(kFormat) naming the file.
nlohmann::json parse_json(std::string_view text, const std::string& file, std::string_view what = "");

}  // namespace visloc
