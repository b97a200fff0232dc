#include "visloc/util/error.h"

namespace visloc {

std::string_view to_string(ErrorCode code) {
  switch (code) {
    case ErrorCode::kInvalidArgument: return "invalid argument";
    case ErrorCode::kIo: return "I/O error";
    case ErrorCode::kFormat: return "bad file format";
    case ErrorCode::kNotFound: return "not found";
    case ErrorCode::kNotImplemented: return "not implemented";
    case ErrorCode::kExternalTool: return "external tool failed";
    case ErrorCode::kInternal: return "internal error";
  }
  return "unknown error";
}

}  // namespace visloc
