// Running an external program (COLMAP) as a child process: no shell, the
// program searched in PATH, stdout and stderr appended to a log file.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace visloc {

struct ProcessResult {
  int exit_code = 0;
  double seconds = 0.0;
};

// Runs argv (argv[0] is the program). Throws Error(kNotFound) when the
// program cannot be found, Error(kExternalTool) when it exits non-zero or
// dies from a signal; the message names the command, the log file and
// quotes the log's last lines.
ProcessResult run_process(const std::vector<std::string>& argv, const std::filesystem::path& log_path);

// The last `lines` lines of a text file ("" if it cannot be read).
std::string tail_of_file(const std::filesystem::path& path, int lines);

// True when `program` is found in PATH (or is an executable path).
bool program_exists(const std::string& program);

}  // namespace visloc
