#include "visloc/util/option_table.h"

#include <cerrno>
#include <cmath>
#include <cstdlib>

namespace visloc {

OptionTable::Entry& OptionTable::push(std::string name, std::string help) {
  VISLOC_CHECK(!name.empty(), "an option needs a name");
  VISLOC_CHECK(find(name) == nullptr, "option declared twice: ", name);
  Entry& e = entries_.emplace_back();
  e.name = std::move(name);
  e.help = std::move(help);
  return e;
}

OptionTable::Entry& OptionTable::flag(std::string name, bool& field, std::string help) {
  Entry& e = push(std::move(name), std::move(help));
  e.field = &field;
  e.flag = true;
  e.show_default = false;
  return e;
}

OptionTable::Entry& OptionTable::action(std::string name, std::function<void()> action, std::string help) {
  Entry& e = push(std::move(name), std::move(help));
  e.parse = [action = std::move(action)](const std::string&) { action(); };
  e.flag = true;
  e.show_default = false;
  return e;
}

OptionTable::Entry& OptionTable::text(std::string name, std::string default_text,
                                      std::function<void(const std::string&)> parse, std::string help) {
  Entry& e = push(std::move(name), std::move(help));
  e.parse = std::move(parse);
  e.show_default = !default_text.empty();
  e.default_text = std::move(default_text);
  return e;
}

void OptionTable::append(const OptionTable& other) {
  for (const Entry& e : other.entries_) {
    VISLOC_CHECK(find(e.name) == nullptr, "option declared twice: ", e.name);
    entries_.push_back(e);
  }
}

namespace {

// "!--no-x" and "--no-x" name the same flag.
std::string plain_name(const std::string& name) { return name.rfind('!', 0) == 0 ? name.substr(1) : name; }

}  // namespace

const OptionTable::Entry* OptionTable::find(const std::string& name) const {
  for (const Entry& e : entries_)
    if (plain_name(e.name) == plain_name(name)) return &e;
  return nullptr;
}

std::vector<double> parse_number_list(const std::string& text, const std::string& option) {
  std::vector<double> out;
  size_t start = 0;
  while (start <= text.size()) {
    const size_t comma = text.find(',', start);
    const std::string item = text.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    char* end = nullptr;
    const double v = item.empty() ? 0.0 : std::strtod(item.c_str(), &end);
    if (item.empty() || end != item.c_str() + item.size() || !std::isfinite(v))
      throw_error(ErrorCode::kInvalidArgument, option, ": '", item, "' is not a finite number (in '", text, "')");
    out.push_back(v);
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return out;
}

double parse_finite_number(const std::string& text, const std::string& option, double lo, double hi) {
  char* end = nullptr;
  const double v = text.empty() ? 0.0 : std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(v))
    throw_error(ErrorCode::kInvalidArgument, option, ": '", text, "' is not a finite number");
  if (v < lo || v > hi) throw_error(ErrorCode::kInvalidArgument, option, ": ", v, " is not in [", lo, ", ", hi, "]");
  return v;
}

long long parse_whole_number(const std::string& text, const std::string& option, long long lo, long long hi) {
  char* end = nullptr;
  errno = 0;
  const long long v = text.empty() ? 0 : std::strtoll(text.c_str(), &end, 10);
  if (text.empty() || end != text.c_str() + text.size() || errno == ERANGE)
    throw_error(ErrorCode::kInvalidArgument, option, ": '", text, "' is not a whole number");
  if (v < lo || v > hi) throw_error(ErrorCode::kInvalidArgument, option, ": ", v, " is not in [", lo, ", ", hi, "]");
  return v;
}

std::pair<int, int> parse_image_size(const std::string& text, const std::string& option) {
  const size_t x = text.find('x');
  auto whole = [&](const std::string& part, int& value) {
    char* end = nullptr;
    const long v = part.empty() ? 0 : std::strtol(part.c_str(), &end, 10);
    if (part.empty() || end != part.c_str() + part.size() || v <= 0 || v > 1 << 20) return false;
    value = static_cast<int>(v);
    return true;
  };
  int w = 0, h = 0;
  if (x == std::string::npos || !whole(text.substr(0, x), w) || !whole(text.substr(x + 1), h))
    throw_error(ErrorCode::kInvalidArgument, option, ": '", text, "' is not WIDTHxHEIGHT (positive whole numbers)");
  return {w, h};
}

}  // namespace visloc
