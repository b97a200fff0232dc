#include "visloc/util/json_fields.h"

#include <cmath>

namespace visloc {

std::string JsonField::type_name() const {
  const nlohmann::json& v = *value_;
  if (v.is_number_float()) {
    std::string s = v.dump();
    return "the number " + (s.size() > 24 ? s.substr(0, 24) + "…" : s);
  }
  if (v.is_number_integer()) return "the integer " + v.dump();
  return std::string(v.type_name());
}

void JsonField::require(bool ok, std::string_view expected) const {
  if (!ok) fail("must be ", expected, ", found ", type_name());
}

bool JsonField::has(std::string_view key) const {
  require(value_->is_object(), "an object");
  auto it = value_->find(key);
  return it != value_->end() && !it->is_null();
}

JsonField JsonField::at(std::string_view key) const {
  require(value_->is_object(), "an object");
  auto it = value_->find(key);
  const std::string child = path_.empty() ? std::string(key) : path_ + "." + std::string(key);
  if (it == value_->end()) throw_error(ErrorCode::kFormat, file_, ": field '", child, "' is missing");
  if (it->is_null()) throw_error(ErrorCode::kFormat, file_, ": field '", child, "' is null");
  return JsonField(*it, file_, child);
}

size_t JsonField::size() const {
  require(value_->is_array(), "an array");
  return value_->size();
}

JsonField JsonField::at(size_t index) const {
  require(value_->is_array(), "an array");
  if (index >= value_->size()) fail("has ", value_->size(), " elements, no element ", index);
  return JsonField((*value_)[index], file_, path_ + "[" + std::to_string(index) + "]");
}

std::string JsonField::string() const {
  require(value_->is_string(), "a string");
  return value_->get<std::string>();
}

bool JsonField::boolean() const {
  require(value_->is_boolean(), "true or false");
  return value_->get<bool>();
}

double JsonField::number() const {
  require(value_->is_number(), "a number");
  const double x = value_->get<double>();
  if (!std::isfinite(x)) fail("must be a finite number, found ", x);
  return x;
}

int64_t JsonField::integer(int64_t lo, int64_t hi) const {
  require(value_->is_number_integer(), "an integer");
  if (value_->is_number_unsigned()) {
    const uint64_t u = value_->get<uint64_t>();
    if (hi < 0 || u > static_cast<uint64_t>(hi)) fail("must be an integer in [", lo, ", ", hi, "], found ", u);
    return static_cast<int64_t>(u);
  }
  const int64_t x = value_->get<int64_t>();
  if (x < lo || x > hi) fail("must be an integer in [", lo, ", ", hi, "], found ", x);
  return x;
}

uint64_t JsonField::unsigned_integer(uint64_t hi) const {
  require(value_->is_number_integer(), "a non-negative integer");
  if (!value_->is_number_unsigned()) fail("must be a non-negative integer, found ", value_->get<int64_t>());
  const uint64_t u = value_->get<uint64_t>();
  if (u > hi) fail("must be at most ", hi, ", found ", u);
  return u;
}

std::vector<double> JsonField::numbers(size_t expected_size) const {
  const size_t n = size();
  if (expected_size != std::string::npos && n != expected_size)
    fail("must hold ", expected_size, " numbers, found ", n);
  std::vector<double> out(n);
  for (size_t i = 0; i < n; ++i) out[i] = at(i).number();
  return out;
}

std::vector<std::string> JsonField::strings() const {
  const size_t n = size();
  std::vector<std::string> out(n);
  for (size_t i = 0; i < n; ++i) out[i] = at(i).string();
  return out;
}

nlohmann::json parse_json(std::string_view text, const std::string& file, std::string_view what) {
  try {
    return nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw_error(ErrorCode::kFormat, file, ": ", what.empty() ? "" : what, what.empty() ? "" : " ",
                "is not valid JSON (", e.what(), ")");
  }
}

}  // namespace visloc
