#include "visloc/sfm/slurm.h"

#include <unistd.h>

#include <cmath>
#include <sstream>

#include "visloc/sfm/process.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {
namespace fs = std::filesystem;

void SlurmOptions::validate() const {
  if (!(poll_seconds > 0) || !std::isfinite(poll_seconds))
    throw_error(ErrorCode::kInvalidArgument, "slurm: poll_seconds must be positive, got ", poll_seconds);
  if (cpus_per_task < 1)
    throw_error(ErrorCode::kInvalidArgument, "slurm: cpus_per_task must be >= 1, got ", cpus_per_task);
  if (job_name.empty()) throw_error(ErrorCode::kInvalidArgument, "slurm: job_name is empty");
  if (!(poll_seconds <= 3600) || !(result_grace_seconds >= 0 && result_grace_seconds <= 3600) ||
      !(unreachable_seconds > 0 && unreachable_seconds <= 86400))
    throw_error(ErrorCode::kInvalidArgument, "slurm: poll, grace and unreachable times must be within bounds");
  if (max_array_size < 1) throw_error(ErrorCode::kInvalidArgument, "slurm: max_array_size must be >= 1");
  // Options that visloc sets itself and that would break how it follows the array.
  std::istringstream extra(extra_args);
  for (std::string a; extra >> a;)
    for (const char* own : {"--array", "-a", "--wrap", "--output", "-o", "--error", "-e", "--parsable", "--job-name",
                            "-J", "--wait", "-W", "--test-only"})
      if (a == own || a.rfind(std::string(own) + "=", 0) == 0)
        throw_error(ErrorCode::kInvalidArgument, "slurm: --slurm-args must not contain ", own,
                    " (visloc sets it to follow the array)");
}

namespace {

// Runs a Slurm client and returns its standard output (and error); throws
// with that text when it fails.
std::string run_capture(const std::vector<std::string>& argv, bool throw_on_failure = true, bool* ok = nullptr,
                        std::string* error_text = nullptr) {
  char tmpl[] = "/tmp/visloc-slurm-XXXXXX";
  const int fd = ::mkstemp(tmpl);
  if (fd < 0) throw_error(ErrorCode::kIo, "slurm: cannot create a temporary file");
  ::close(fd);
  const fs::path out = tmpl;
  std::string text;
  try {
    run_process(argv, out);
    text = read_file(out);
  } catch (const Error& e) {
    std::error_code ec;
    fs::remove(out, ec);
    if (throw_on_failure) throw;
    if (ok) *ok = false;
    if (error_text) *error_text = e.what();
    return "";
  }
  if (ok) *ok = true;
  std::error_code ec;
  fs::remove(out, ec);
  // run_process heads its log with "\n$ command\n": keep only the program's output.
  if (text.rfind("\n$ ", 0) == 0) {
    const size_t eol = text.find('\n', 1);
    text.erase(0, eol == std::string::npos ? text.size() : eol + 1);
  }
  return text;
}

std::string field(const std::string& line, const std::string& key) {
  const std::string k = key + "=";
  size_t p = 0;
  while ((p = line.find(k, p)) != std::string::npos) {
    if (p == 0 || line[p - 1] == ' ') {
      const size_t e = line.find(' ', p);
      return line.substr(p + k.size(), e == std::string::npos ? std::string::npos : e - p - k.size());
    }
    p += k.size();
  }
  return "";
}

}  // namespace

std::string shell_quote(const std::string& arg) {
  std::string q = "'";
  for (char c : arg) {
    if (c == '\'') q += "'\\''";
    else q += c;
  }
  return q + "'";
}

SlurmArray SlurmArray::submit(const SlurmOptions& options, const std::vector<int>& indices,
                              const std::vector<std::string>& command, const fs::path& log_dir) {
  options.validate();
  if (indices.empty()) throw_error(ErrorCode::kInvalidArgument, "slurm: an array needs at least one task");
  if (command.empty()) throw_error(ErrorCode::kInvalidArgument, "slurm: empty task command");
  if (!program_exists("sbatch"))
    throw_error(ErrorCode::kNotFound, "slurm: sbatch is not on the PATH (install slurm-wlm, or use --executor local)");
  fs::create_directories(log_dir);
  // Slurm expands % in -o; a literal % is %%.
  std::string log_pattern;
  for (char c : fs::absolute(log_dir).string()) log_pattern += c == '%' ? std::string("%%") : std::string(1, c);
  log_pattern += "/%A_%a.log";
  std::string array;
  for (int i : indices) array += (array.empty() ? "" : ",") + std::to_string(i);
  std::string wrap = "exec";
  for (const auto& a : command) wrap += " " + shell_quote(a);
  wrap += " \"$SLURM_ARRAY_TASK_ID\"";
  std::vector<std::string> argv = {"sbatch", "--parsable", "--array=" + array, "-J", options.job_name,
                                   "--cpus-per-task=" + std::to_string(options.cpus_per_task),
                                   "-o", log_pattern};
  if (!options.partition.empty()) argv.push_back("--partition=" + options.partition);
  std::istringstream extra(options.extra_args);
  for (std::string a; extra >> a;) argv.push_back(a);
  argv.push_back("--wrap=" + wrap);
  const std::string out = run_capture(argv);
  // --parsable: a line "jobid" or "jobid;cluster" (after any warnings).
  std::string id;
  std::istringstream lines(out);
  for (std::string line; std::getline(lines, line);) {
    line = line.substr(0, line.find(';'));
    while (!line.empty() && (line.back() == ' ' || line.back() == '\r')) line.pop_back();
    if (!line.empty() && line.find_first_not_of("0123456789") == std::string::npos) id = line;
  }
  if (id.empty() || id.find_first_not_of("0123456789") != std::string::npos)
    throw_error(ErrorCode::kExternalTool, "slurm: sbatch did not return a job id: ", out);
  SlurmArray a;
  a.options_ = options;
  a.job_id_ = id;
  a.log_dir_ = fs::absolute(log_dir);
  return a;
}

SlurmArray SlurmArray::attach(const SlurmOptions& options, const std::string& job_id, const fs::path& log_dir) {
  SlurmArray a;
  a.options_ = options;
  a.job_id_ = job_id;
  a.log_dir_ = fs::absolute(log_dir);
  return a;
}

SlurmArray::State SlurmArray::poll() const {
  bool ok = false;
  std::string error;
  const std::string out = run_capture({"squeue", "-h", "-j", job_id_, "-o", "%i"}, false, &ok, &error);
  // squeue fails with "Invalid job id" once Slurm has forgotten the job: done.
  if (!ok) return error.find("Invalid job id") != std::string::npos ? State::kDone : State::kUnknown;
  return out.find_first_not_of(" \n") != std::string::npos ? State::kRunning : State::kDone;
}

std::map<int, SlurmTaskState> SlurmArray::task_states() const {
  std::map<int, SlurmTaskState> states;
  const std::string out = run_capture({"scontrol", "-o", "show", "job", job_id_}, false);
  std::istringstream lines(out);
  for (std::string line; std::getline(lines, line);) {
    const std::string task = field(line, "ArrayTaskId");
    if (task.empty() || task.find_first_not_of("0123456789") != std::string::npos) continue;  // pending ranges
    SlurmTaskState s;
    s.state = field(line, "JobState");
    const std::string ec = field(line, "ExitCode");
    const size_t colon = ec.find(':');
    try {
      s.exit_code = std::stoi(ec.substr(0, colon));
      if (colon != std::string::npos) s.signal = std::stoi(ec.substr(colon + 1));
    } catch (const std::exception&) {
    }
    states[std::stoi(task)] = s;
  }
  return states;
}

fs::path SlurmArray::task_log(int index) const {
  return log_dir_ / (job_id_ + "_" + std::to_string(index) + ".log");
}

void SlurmArray::cancel() const { run_capture({"scancel", job_id_}, false); }

bool slurm_available() {
  if (!program_exists("sbatch") || !program_exists("sinfo")) return false;
  try {
    run_capture({"sinfo", "-h"});
    return true;
  } catch (const Error&) {
    return false;
  }
}

}  // namespace visloc
