// Binds an OptionTable (util/option_table.h: the options the library declares
// beside its structs) to a CLI11 command.
#pragma once

#include <CLI/CLI.hpp>

#include "visloc/util/option_table.h"

namespace visloc::cli {

// Adds every entry of `table` to `cmd`: typed fields parsed by CLI11 (ranges
// checked, NaN refused by main), text entries by their parse function, whose
// Error becomes a usage error (exit 2) naming the option.
void bind_options(CLI::App* cmd, const OptionTable& table);

}  // namespace visloc::cli
