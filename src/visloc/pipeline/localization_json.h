// The JSON line of `visloc localize` (DESIGN.md): one object per query.
#pragma once

#include <nlohmann/json.hpp>

#include "visloc/pipeline/localizer.h"

namespace visloc {

nlohmann::json to_json(const LocalizationResult& r);

}  // namespace visloc
