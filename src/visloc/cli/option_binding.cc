#include "visloc/cli/option_binding.h"

#include <cmath>
#include <cstdlib>
#include <sstream>

namespace visloc::cli {
namespace {

// The entry's numeric range as a validator (CLI::Range prints denormals and lets NaN through).
CLI::Validator range_check(double lo, double hi) {
  std::ostringstream what;
  if (std::isinf(hi) && lo > 0 && lo < 1e-300) what << "> 0";
  else if (std::isinf(hi)) what << ">= " << lo;
  else if (std::isinf(lo)) what << "<= " << hi;
  else what << "in [" << lo << ", " << hi << "]";
  const std::string bound = what.str();
  return CLI::Validator(
      [lo, hi, bound](std::string& text) -> std::string {
        char* end = nullptr;
        const double v = std::strtod(text.c_str(), &end);
        if (end == text.c_str()) return {};  // not a number: CLI11's conversion reports it
        if (!(v >= lo && v <= hi)) return "'" + text + "' is not " + bound;
        return {};
      },
      bound);
}

// The entry's parse function, its Error reported as a usage error (exit 2).
std::function<void(const std::string&)> parse_as_usage(const OptionTable::Entry& e) {
  return [parse = e.parse](const std::string& text) {
    try {
      parse(text);
    } catch (const Error& error) {
      throw CLI::ValidationError(error.what());
    }
  };
}

void bind_entry(CLI::App* cmd, const OptionTable::Entry& e) {
  CLI::Option* o = nullptr;
  if (e.flag) {
    if (bool* const* field = std::get_if<bool*>(&e.field)) {
      o = cmd->add_flag(e.name, **field, e.help);
    } else {
      o = cmd->add_flag_callback(e.name, [parse = parse_as_usage(e)] { parse(""); }, e.help);
    }
  } else if (e.parse) {
    o = cmd->add_option_function<std::string>(e.name, parse_as_usage(e), e.help);
  } else {
    std::visit(
        [&](auto field) {
          if constexpr (!std::is_same_v<decltype(field), std::monostate>) o = cmd->add_option(e.name, *field, e.help);
        },
        e.field);
  }
  if (o == nullptr) throw CLI::ConstructionError("option " + e.name + " has no field", 1);
  if (e.show_default && !e.default_text.empty()) o->default_str(e.default_text);
  if (!e.choices.empty()) o->check(CLI::IsMember(e.choices));
  if (!std::isinf(e.min) || !std::isinf(e.max)) o->check(range_check(e.min, e.max));
  if (e.required) o->required();
  if (e.take_last) o->take_last();
  if (e.delimiter != 0) o->delimiter(e.delimiter);
}

}  // namespace

void bind_options(CLI::App* cmd, const OptionTable& table) {
  for (const OptionTable::Entry& e : table.entries()) bind_entry(cmd, e);
}

}  // namespace visloc::cli
