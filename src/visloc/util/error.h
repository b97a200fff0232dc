// Errors: one exception type for problems a user can fix (bad file, bad
// argument), with a code the CLI maps to an exit status. Internal invariants
// use VISLOC_CHECK, which throws ErrorCode::kInternal (the library never
// aborts or exits).
#pragma once

#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>

namespace visloc {

enum class ErrorCode {
  kInvalidArgument,  // a bad option or argument value
  kIo,               // a file cannot be opened, read or written
  kFormat,           // a file exists but its content is wrong
  kNotFound,         // something named does not exist
  kNotImplemented,   // a feature that is not built yet
  kExternalTool,     // an external program (COLMAP) failed
  kInternal,         // a bug: an invariant did not hold
};

std::string_view to_string(ErrorCode code);

class Error : public std::runtime_error {
 public:
  Error(ErrorCode code, const std::string& message)
      : std::runtime_error(message), code_(code) {}
  ErrorCode code() const { return code_; }

 private:
  ErrorCode code_;
};

// Builds a message from streamable parts: throw_error(kIo, "cannot open ", path).
template <typename... Parts>
[[noreturn]] void throw_error(ErrorCode code, const Parts&... parts) {
  std::ostringstream s;
  (s << ... << parts);
  throw Error(code, s.str());
}

}  // namespace visloc

#define VISLOC_CHECK(cond, ...)                                                  \
  do {                                                                           \
    if (!(cond))                                                                 \
      ::visloc::throw_error(::visloc::ErrorCode::kInternal, __FILE__, ":",       \
                            __LINE__, ": check failed: " #cond " " __VA_ARGS__); \
  } while (0)
