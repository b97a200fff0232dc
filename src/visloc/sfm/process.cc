#include "visloc/sfm/process.h"

#include <fcntl.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <fstream>
#include <sstream>

#include "visloc/util/error.h"
#include "visloc/util/timer.h"

extern char** environ;

namespace visloc {

std::string tail_of_file(const std::filesystem::path& path, int lines) {
  std::ifstream in(path);
  std::deque<std::string> last;
  std::string line;
  while (std::getline(in, line)) {
    last.push_back(line);
    if (static_cast<int>(last.size()) > lines) last.pop_front();
  }
  std::ostringstream s;
  for (const auto& l : last) s << "    " << l << "\n";
  return s.str();
}

bool program_exists(const std::string& program) {
  if (program.find('/') != std::string::npos) return ::access(program.c_str(), X_OK) == 0;
  const char* path = std::getenv("PATH");
  std::istringstream dirs(path ? path : "/usr/bin:/bin");
  std::string dir;
  while (std::getline(dirs, dir, ':'))
    if (!dir.empty() && ::access((dir + "/" + program).c_str(), X_OK) == 0) return true;
  return false;
}

ProcessResult run_process(const std::vector<std::string>& argv, const std::filesystem::path& log_path) {
  VISLOC_CHECK(!argv.empty());
  std::string command;
  for (const auto& a : argv) command += (command.empty() ? "" : " ") + a;
  if (!program_exists(argv[0]))
    throw_error(ErrorCode::kNotFound, "program '", argv[0], "' not found in PATH",
                argv[0] == "colmap" ? " (install COLMAP: scripts/setup.sh, or apt-get install colmap)" : "");
  int log_fd = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (log_fd < 0) throw_error(ErrorCode::kIo, "cannot open log file ", log_path.string(), ": ", std::strerror(errno));
  {
    std::string header = "\n$ " + command + "\n";
    if (::write(log_fd, header.data(), header.size()) < 0) { /* the log is best effort */ }
  }
  // The program's full path, found before fork: between fork and exec the
  // child only makes async-signal-safe calls.
  std::string program = argv[0];
  if (program.find('/') == std::string::npos) {
    const char* path = std::getenv("PATH");
    std::istringstream dirs(path ? path : "/usr/bin:/bin");
    for (std::string dir; std::getline(dirs, dir, ':');)
      if (!dir.empty() && ::access((dir + "/" + program).c_str(), X_OK) == 0) {
        program = dir + "/" + program;
        break;
      }
  }
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  int null_fd = ::open("/dev/null", O_RDONLY | O_CLOEXEC);
  if (null_fd < 0) {
    ::close(log_fd);
    throw_error(ErrorCode::kIo, "cannot open /dev/null: ", std::strerror(errno));
  }
  // Both above 2, so that the child's dup2 onto 0-2 never overwrites one with
  // the other (a process started with a standard stream closed).
  for (int* fd : {&log_fd, &null_fd})
    if (*fd <= 2) {
      const int moved = ::fcntl(*fd, F_DUPFD_CLOEXEC, 3);
      ::close(*fd);
      *fd = moved;
    }
  if (log_fd < 0 || null_fd < 0) {
    if (log_fd >= 0) ::close(log_fd);
    if (null_fd >= 0) ::close(null_fd);
    throw_error(ErrorCode::kIo, "cannot set up the standard streams of '", command, "'");
  }
  static const char kExecFailed[] = "visloc: cannot execute the program (execv failed)\n";
  Timer timer;
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid == 0) {
    // The child dies with us: a killed `map build` leaves no COLMAP running
    // on in its work folder (PR_SET_PDEATHSIG; the getppid check closes the
    // race with a parent that died before prctl).
    if (::prctl(PR_SET_PDEATHSIG, SIGKILL) != 0 || ::getppid() != parent) ::_exit(127);
    if (::dup2(null_fd, STDIN_FILENO) < 0 || ::dup2(log_fd, STDOUT_FILENO) < 0 || ::dup2(log_fd, STDERR_FILENO) < 0)
      ::_exit(127);
    ::execv(program.c_str(), args.data());
    if (::write(STDERR_FILENO, kExecFailed, sizeof(kExecFailed) - 1) < 0) { /* nothing left to report to */ }
    ::_exit(127);
  }
  const int spawn_errno = errno;
  ::close(null_fd);
  ::close(log_fd);
  if (pid < 0) throw_error(ErrorCode::kExternalTool, "cannot start '", command, "': ", std::strerror(spawn_errno));
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0) {
    if (errno != EINTR) throw_error(ErrorCode::kExternalTool, "waiting for '", command, "': ", std::strerror(errno));
  }
  ProcessResult result;
  result.seconds = timer.elapsed_ms() / 1000.0;
  if (WIFSIGNALED(status))
    throw_error(ErrorCode::kExternalTool, "'", argv[0], "' was killed by signal ", WTERMSIG(status), " (log: ",
                log_path.string(), ")\n", tail_of_file(log_path, 8));
  result.exit_code = WEXITSTATUS(status);
  if (result.exit_code != 0)
    throw_error(ErrorCode::kExternalTool, "'", command, "' failed with exit status ", result.exit_code,
                " (log: ", log_path.string(), "); last lines:\n", tail_of_file(log_path, 8));
  return result;
}

}  // namespace visloc
