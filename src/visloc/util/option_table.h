// A command's options declared once, in the library, beside the options
// structs they fill: each entry has a name, help text and the field it sets
// (or a function that parses its text). A front end binds the table: the CLI
// with CLI11 (cli/option_binding.h), `map build-segment` when it re-reads the
// options a Slurm build recorded. Like COLMAP's OptionManager, which keeps
// COLMAP's executables to a few lines each, but without a parser of its own:
// typed fields are parsed by the front end, text entries by `parse`.
//
//   OptionTable t;
//   add_options(t, sift_options);                 // each module describes its structs
//   t.add("--top-images", o.top_images, "Retrieval: images N_t");
//   t.flag("!--no-fallback", o.full_search_fallback, "Do not search all features again");
//   t.choice("--matcher", o.matcher, {{"auto", PairMatcher::kDefault}, {"guided", PairMatcher::kGuided}}, "...");
#pragma once

#include <deque>
#include <filesystem>
#include <functional>
#include <limits>
#include <sstream>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "visloc/util/error.h"

namespace visloc {

class OptionTable {
 public:
  // The typed fields a front end parses itself.
  using Field = std::variant<std::monostate, bool*, int*, long*, long long*, unsigned*, unsigned long*,
                             unsigned long long*, float*, double*, std::string*, std::filesystem::path*,
                             std::vector<std::string>*, std::vector<int>*, std::vector<unsigned long>*,
                             std::vector<double>*>;

  struct Entry {
    // "--name" for an option, "!--no-name" for a flag that sets false, a bare
    // word ("map") for a positional argument.
    std::string name;
    std::string help;
    Field field;
    // Set instead of `field`: parses the option's text into the options
    // (choices, lists, sizes) and throws Error(kInvalidArgument) when it cannot.
    std::function<void(const std::string&)> parse;
    std::string default_text;  // shown in --help when show_default
    std::vector<std::string> choices;
    bool flag = false;  // takes no value
    bool required = false;
    bool show_default = true;
    bool take_last = false;  // given twice, the last wins (otherwise an error)
    char delimiter = 0;      // list fields: also split each value at this character ("1,2,3")
    double min = -std::numeric_limits<double>::infinity();
    double max = std::numeric_limits<double>::infinity();

    Entry& require() { required = true; show_default = false; return *this; }
    Entry& range(double lo, double hi) { min = lo; max = hi; return *this; }
    Entry& non_negative() { return range(0, std::numeric_limits<double>::infinity()); }
    Entry& positive() { min = std::numeric_limits<double>::denorm_min(); return *this; }
    Entry& one_of(std::vector<std::string> values) { choices = std::move(values); return *this; }
    Entry& no_default() { show_default = false; return *this; }
    Entry& last_wins() { take_last = true; return *this; }
    Entry& split_at(char c) { delimiter = c; return *this; }
  };

  // An option with a value, parsed by the front end into `field`; --help
  // shows the field's value now as the default.
  template <class T>
  Entry& add(std::string name, T& field, std::string help) {
    Entry& e = push(std::move(name), std::move(help));
    e.field = &field;
    if constexpr (std::is_same_v<T, std::vector<std::string>> || std::is_same_v<T, std::vector<int>> ||
                  std::is_same_v<T, std::vector<unsigned long>> ||
                  std::is_same_v<T, std::vector<double>>) {
      e.show_default = !field.empty();
      e.default_text = join(field);
    } else {
      e.default_text = to_text(field);
      e.show_default = !e.default_text.empty();
    }
    return e;
  }
  // A flag: "--name" sets the field to true, "!--no-name" to false.
  Entry& flag(std::string name, bool& field, std::string help);
  // A flag that runs `action` when given.
  Entry& action(std::string name, std::function<void()> action, std::string help);
  // An option whose text is parsed by `parse` (throws Error(kInvalidArgument)).
  Entry& text(std::string name, std::string default_text, std::function<void(const std::string&)> parse,
              std::string help);
  // One of named values, e.g. {{"local", Executor::kLocal}, {"slurm", Executor::kSlurm}}.
  template <class Enum>
  Entry& choice(std::string name, Enum& field, std::vector<std::pair<std::string, Enum>> values, std::string help) {
    std::string current;
    std::vector<std::string> names;
    for (const auto& [text, value] : values) {
      names.push_back(text);
      if (value == field && current.empty()) current = text;
    }
    const std::string option = name;
    Entry& e = this->text(
        std::move(name), current,
        [&field, values, option](const std::string& text) {
          for (const auto& [t, value] : values)
            if (t == text) {
              field = value;
              return;
            }
          throw_error(ErrorCode::kInvalidArgument, option, ": '", text, "' is not one of the choices");
        },
        std::move(help));
    e.choices = std::move(names);
    return e;
  }

  // Every entry of `other`, after this table's.
  void append(const OptionTable& other);
  const std::deque<Entry>& entries() const { return entries_; }
  // The entry named `name` ("--x", "!--no-x" or "--no-x" all find a negated flag); nullptr if none.
  const Entry* find(const std::string& name) const;

 private:
  Entry& push(std::string name, std::string help);
  template <class T>
  static std::string to_text(const T& value) {
    if constexpr (std::is_same_v<T, bool>) {
      return value ? "true" : "false";
    } else if constexpr (std::is_same_v<T, std::filesystem::path>) {
      return value.string();
    } else {
      std::ostringstream s;
      s << value;
      return s.str();
    }
  }
  template <class V>
  static std::string join(const V& values) {
    std::string out;
    for (const auto& v : values) {
      if (!out.empty()) out += ",";
      out += to_text(v);
    }
    return out;
  }
  std::deque<Entry> entries_;  // a deque: references returned by add() stay valid
};

// "1,2.5,3" → {1, 2.5, 3}: finite numbers only; throws Error(kInvalidArgument)
// naming `option` and the item.
std::vector<double> parse_number_list(const std::string& text, const std::string& option);
// A finite number, or a whole number, in [lo, hi]; throws Error(kInvalidArgument) naming `option`.
double parse_finite_number(const std::string& text, const std::string& option,
                           double lo = -std::numeric_limits<double>::max(),
                           double hi = std::numeric_limits<double>::max());
long long parse_whole_number(const std::string& text, const std::string& option,
                             long long lo = std::numeric_limits<long long>::min(),
                             long long hi = std::numeric_limits<long long>::max());
// "640x480" → {640, 480}, both > 0; throws Error(kInvalidArgument) naming `option`.
std::pair<int, int> parse_image_size(const std::string& text, const std::string& option);

}  // namespace visloc
