// Slurm job arrays for map building (issue #12): one task per segment, each
// running a command on a node that sees the map directory. Drives Slurm's
// own client programs (sbatch, squeue, scontrol, scancel) as processes; it
// needs no slurmdbd (sacct is not used).
#pragma once

#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace visloc {

struct SlurmOptions {
  std::string partition;        // empty: the cluster's default partition
  std::string extra_args;       // more sbatch options, split at whitespace (e.g. "--mem=8G --time=2:00:00")
  std::string job_name = "visloc-map";
  int cpus_per_task = 1;
  double poll_seconds = 5.0;    // squeue polling while waiting for the array (progress files: every second)
  double result_grace_seconds = 60;  // after the array ends, how long to wait for results to appear
                                     // (a shared filesystem may show another node's files late)
  double unreachable_seconds = 600;  // squeue failing this long: stop waiting (the array is left alone)
  size_t max_array_size = 1000;      // tasks per array (Slurm's MaxArraySize − 1 by default); more: several arrays
  void validate() const;
};

struct SlurmTaskState {
  std::string state;  // PENDING, RUNNING, COMPLETED, FAILED, CANCELLED, TIMEOUT, ... ("" when Slurm forgot it)
  int exit_code = 0;
  int signal = 0;
};

class SlurmArray {
 public:
  // Submits `command` (argv; the task index is appended as the last
  // argument) as one array with the given task indices. Each task's output
  // goes to log_dir/<job>_<index>.log. Throws Error(kNotFound) without
  // sbatch, Error(kExternalTool) when sbatch refuses (its message quoted).
  static SlurmArray submit(const SlurmOptions& options, const std::vector<int>& indices,
                           const std::vector<std::string>& command, const std::filesystem::path& log_dir);

  // An array submitted earlier (e.g. by an interrupted run), by its job id.
  static SlurmArray attach(const SlurmOptions& options, const std::string& job_id,
                           const std::filesystem::path& log_dir);

  const std::string& job_id() const { return job_id_; }
  // kRunning while squeue lists a task of the array, kDone once it lists
  // none (or no longer knows the job), kUnknown when squeue itself failed.
  enum class State { kRunning, kDone, kUnknown };
  State poll() const;
  // State of every task Slurm still remembers (scontrol; MinJobAge).
  std::map<int, SlurmTaskState> task_states() const;
  std::filesystem::path task_log(int index) const;
  void cancel() const;

 private:
  SlurmOptions options_;
  std::string job_id_;
  std::filesystem::path log_dir_;
};

// True when sbatch is on the PATH and a controller answers (sinfo exits 0).
bool slurm_available();

// Quotes one argument for a POSIX shell ('...').
std::string shell_quote(const std::string& arg);

}  // namespace visloc
