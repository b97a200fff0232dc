#include "visloc/sfm/process.h"

#include <fcntl.h>
#include <pthread.h>
#include <sched.h>
#include <sys/prctl.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <fstream>
#include <memory>
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

namespace {

// What the child needs, prepared by the parent: between clone and execve the
// child only makes system calls.
struct ChildSetup {
  const char* program = nullptr;
  char* const* argv = nullptr;
  char* const* envp = nullptr;
  int stdin_fd = -1;
  int output_fd = -1;
  pid_t parent = 0;
  sigset_t parent_mask{};
  int failed_errno = 0;  // set by the child when it cannot reach execve
};

// The child's side, on its own stack and in the parent's memory until execve
// (CLONE_VM | CLONE_VFORK: the parent waits meanwhile). Not instrumented:
// sanitizer bookkeeping here would run on the suspended parent thread's state.
__attribute__((no_sanitize("address", "undefined"))) int child_main(void* arg) {
  auto* setup = static_cast<ChildSetup*>(arg);
  // A handler the embedding program installed is its code on memory shared
  // until execve: back to the default before the signals are unblocked.
  for (int sig = 1; sig < NSIG; ++sig) {
    struct sigaction action;
    std::memset(&action, 0, sizeof action);
    if (::sigaction(sig, nullptr, &action) != 0) continue;
    if (action.sa_handler == SIG_DFL || action.sa_handler == SIG_IGN) continue;
    std::memset(&action, 0, sizeof action);
    action.sa_handler = SIG_DFL;
    ::sigaction(sig, &action, nullptr);
  }
  int failed = 0;
  // The child dies with the thread that started it: a killed `map build`
  // leaves no COLMAP running on in its work folder (PR_SET_PDEATHSIG; the
  // getppid check closes the race with a parent that died before prctl).
  if (::prctl(PR_SET_PDEATHSIG, SIGKILL) != 0 || ::getppid() != setup->parent)
    failed = ESRCH;
  else if (::dup2(setup->stdin_fd, STDIN_FILENO) < 0 || ::dup2(setup->output_fd, STDOUT_FILENO) < 0 ||
           ::dup2(setup->output_fd, STDERR_FILENO) < 0)
    failed = errno;
  if (failed == 0) {
    ::pthread_sigmask(SIG_SETMASK, &setup->parent_mask, nullptr);
    ::execve(setup->program, setup->argv, setup->envp);
    failed = errno;
  }
  setup->failed_errno = failed;
  ::syscall(SYS_exit_group, 127);  // never _exit: its sanitizer hook would run here
  return 127;
}

// Starts the child the way glibc's posix_spawn does, plus the death signal:
// clone with CLONE_VM | CLONE_VFORK, all signals blocked meanwhile. Unlike
// fork in a process whose other threads are busy (segments built in
// parallel), no pthread_atfork handler runs (OpenBLAS's stops its thread
// pool), nothing is copied, and the child takes no lock another thread may
// hold. Returns the pid, or -1 with errno set.
pid_t spawn_child(ChildSetup& setup) {
  // The child's stack: heap memory, which the sanitizers know as addressable.
  constexpr size_t kStackBytes = 256 * 1024;
  const std::unique_ptr<char[]> stack(new char[kStackBytes]);
  char* const stack_top =
      reinterpret_cast<char*>((reinterpret_cast<uintptr_t>(stack.get()) + kStackBytes) & ~uintptr_t{63});
  sigset_t all;
  ::sigfillset(&all);
  ::pthread_sigmask(SIG_BLOCK, &all, &setup.parent_mask);
  const pid_t pid = ::clone(child_main, stack_top, CLONE_VM | CLONE_VFORK | SIGCHLD, &setup);
  const int clone_errno = errno;
  ::pthread_sigmask(SIG_SETMASK, &setup.parent_mask, nullptr);
  errno = clone_errno;
  return pid;
}

}  // namespace

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
  ChildSetup setup;
  setup.program = program.c_str();
  setup.argv = args.data();
  setup.envp = environ;
  setup.stdin_fd = null_fd;
  setup.output_fd = log_fd;
  setup.parent = ::getpid();
  Timer timer;
  const pid_t pid = spawn_child(setup);
  const int spawn_errno = errno;
  ::close(null_fd);
  ::close(log_fd);
  if (pid < 0) throw_error(ErrorCode::kExternalTool, "cannot start '", command, "': ", std::strerror(spawn_errno));
  if (setup.failed_errno != 0) {  // the child exited before or at execve; reap it
    while (::waitpid(pid, nullptr, 0) < 0 && errno == EINTR) {
    }
    throw_error(ErrorCode::kExternalTool, "cannot execute '", command, "': ", std::strerror(setup.failed_errno),
                " (log: ", log_path.string(), ")");
  }
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
