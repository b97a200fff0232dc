#include "visloc/sfm/process.h"

#include <fcntl.h>
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

// The child's raw system calls assume the kernel ABI of x86-64 and aarch64
// Linux: 64 signals, a sigaction whose first 64-bit word is the handler.
#if !defined(__linux__) || !(defined(__x86_64__) || defined(__aarch64__))
#error "process.cc: the child's raw system calls are written for x86-64 and aarch64 Linux"
#endif

// The kernel's signal set: 64 signals (_NSIG on x86-64 and aarch64), the
// size the rt_sig* system calls take.
using KernelSignalSet = uint64_t;
constexpr size_t kKernelSignalSetBytes = sizeof(KernelSignalSet);
constexpr int kKernelSignals = 64;
constexpr size_t kChildStackBytes = 256 * 1024;

// What the child needs, prepared by the parent: between clone and execve the
// child only makes raw system calls (no libc wrapper and no sanitizer
// interceptor, which could touch state it shares with the parent).
struct ChildSetup {
  const char* program = nullptr;
  char* const* argv = nullptr;
  char* const* envp = nullptr;
  int stdin_fd = -1;
  int output_fd = -1;
  pid_t parent = 0;
  KernelSignalSet parent_mask = 0;  // the calling thread's mask, restored before execve
  // Kernel sigactions, made by the parent: SIG_DFL and SIG_IGN with no flags.
  uint64_t default_action[8] = {reinterpret_cast<uintptr_t>(SIG_DFL)};
  uint64_t ignore_action[8] = {reinterpret_cast<uintptr_t>(SIG_IGN)};
  int failed_errno = 0;             // set by the child when it cannot reach execve
};

// The child's side, on its own stack and in the parent's memory until execve
// (CLONE_VM | CLONE_VFORK: the parent thread waits meanwhile). Compiled
// without sanitizer checks or coverage hooks: their bookkeeping would run on
// the suspended thread's state.
#if defined(__clang__)
#define VISLOC_CHILD_UNINSTRUMENTED __attribute__((no_sanitize("address", "undefined", "coverage")))
#else
#define VISLOC_CHILD_UNINSTRUMENTED __attribute__((no_sanitize("address", "undefined")))
#endif
VISLOC_CHILD_UNINSTRUMENTED int child_main(void* arg) {
  auto* setup = static_cast<ChildSetup*>(arg);
  // A handler of the embedding program is its code on memory shared until
  // execve: back to the default before the signals are unblocked (glibc's
  // internal signals 32 and 33 to ignored, as posix_spawn does). The kernel
  // writes its whole sigaction (32 bytes) into `action`; the handler is its
  // first word.
  for (int sig = 1; sig <= kKernelSignals; ++sig) {
    uint64_t action[8];  // no initializer: a compiler may zero it with memset, an interceptor
    if (::syscall(SYS_rt_sigaction, sig, nullptr, action, kKernelSignalSetBytes) != 0) continue;
    if (action[0] == setup->default_action[0] || action[0] == setup->ignore_action[0]) continue;
    ::syscall(SYS_rt_sigaction, sig, sig == 32 || sig == 33 ? setup->ignore_action : setup->default_action, nullptr,
              kKernelSignalSetBytes);
  }
  int failed = 0;
  // The child dies with the thread that started it: a killed `map build`
  // leaves no COLMAP running on in its work folder (PR_SET_PDEATHSIG; the
  // getppid check closes the race with a parent that died before prctl).
  if (::syscall(SYS_prctl, PR_SET_PDEATHSIG, static_cast<unsigned long>(SIGKILL), 0UL, 0UL, 0UL) != 0 ||
      ::syscall(SYS_getppid) != setup->parent)
    failed = ESRCH;
  else if (::syscall(SYS_dup3, setup->stdin_fd, STDIN_FILENO, 0) < 0 ||
           ::syscall(SYS_dup3, setup->output_fd, STDOUT_FILENO, 0) < 0 ||
           ::syscall(SYS_dup3, setup->output_fd, STDERR_FILENO, 0) < 0)  // fds > 2: dup3 never sees equal ones
    failed = errno;
  if (failed == 0) {
    ::syscall(SYS_rt_sigprocmask, SIG_SETMASK, &setup->parent_mask, nullptr, kKernelSignalSetBytes);
    ::syscall(SYS_execve, setup->program, setup->argv, setup->envp);
    failed = errno;
  }
  setup->failed_errno = failed;
  ::syscall(SYS_exit_group, 127);
  return 127;
}

// Starts the child the way glibc's posix_spawn does, plus the death signal:
// clone with CLONE_VM | CLONE_VFORK, every signal blocked meanwhile. Unlike
// fork from a process whose other threads are busy (segments built in
// parallel), no pthread_atfork handler runs, no memory is copied with locks
// other threads hold, and the child makes no call that could take one.
// `stack` holds kChildStackBytes. Returns the pid, or -1 with errno set.
pid_t spawn_child(ChildSetup& setup, char* stack) {
  char* const stack_top = reinterpret_cast<char*>((reinterpret_cast<uintptr_t>(stack) + kChildStackBytes) &
                                                  ~uintptr_t{63});  // stacks grow down
  const KernelSignalSet all = ~KernelSignalSet{0};
  if (::syscall(SYS_rt_sigprocmask, SIG_BLOCK, &all, &setup.parent_mask, kKernelSignalSetBytes) != 0) return -1;
  const pid_t pid = ::clone(child_main, stack_top, CLONE_VM | CLONE_VFORK | SIGCHLD, &setup);
  const int clone_errno = errno;
  ::syscall(SYS_rt_sigprocmask, SIG_SETMASK, &setup.parent_mask, nullptr, kKernelSignalSetBytes);
  errno = clone_errno;
  return pid;
}

// A file descriptor closed when it goes out of scope.
struct OwnedDescriptor {
  int fd = -1;
  explicit OwnedDescriptor(int descriptor) : fd(descriptor) {}
  OwnedDescriptor(const OwnedDescriptor&) = delete;
  OwnedDescriptor& operator=(const OwnedDescriptor&) = delete;
  ~OwnedDescriptor() { reset(-1); }
  void reset(int descriptor) {
    if (fd >= 0) ::close(fd);
    fd = descriptor;
  }
};

}  // namespace

ProcessResult run_process(const std::vector<std::string>& argv, const std::filesystem::path& log_path) {
  VISLOC_CHECK(!argv.empty());
  std::string command;
  for (const auto& a : argv) command += (command.empty() ? "" : " ") + a;
  if (!program_exists(argv[0]))
    throw_error(ErrorCode::kNotFound, "program '", argv[0], "' not found in PATH",
                argv[0] == "colmap" ? " (install COLMAP: scripts/setup.sh, or apt-get install colmap)" : "");
  // Everything that allocates comes before the descriptors are opened.
  const std::unique_ptr<char[]> child_stack(new char[kChildStackBytes]);  // heap: addressable to the sanitizers
  const std::string header = "\n$ " + command + "\n";
  // The program's full path, found here: the child only makes system calls
  // (execve searches no PATH).
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
  OwnedDescriptor log(::open(log_path.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644));
  if (log.fd < 0) {
    const int open_errno = errno;
    throw_error(ErrorCode::kIo, "cannot open log file ", log_path.string(), ": ", std::strerror(open_errno));
  }
  [[maybe_unused]] const ssize_t header_written = ::write(log.fd, header.data(), header.size());  // best effort
  OwnedDescriptor null_input(::open("/dev/null", O_RDONLY | O_CLOEXEC));
  if (null_input.fd < 0) {
    const int open_errno = errno;
    throw_error(ErrorCode::kIo, "cannot open /dev/null: ", std::strerror(open_errno));
  }
  // Both above 2, so that the child's dup3 onto 0-2 never overwrites one with
  // the other (a process started with a standard stream closed).
  for (OwnedDescriptor* d : {&log, &null_input})
    if (d->fd <= 2) {
      d->reset(::fcntl(d->fd, F_DUPFD_CLOEXEC, 3));
      if (d->fd < 0) {
        const int dup_errno = errno;
        throw_error(ErrorCode::kIo, "cannot set up the standard streams of '", command,
                    "': ", std::strerror(dup_errno));
      }
    }
  ChildSetup setup;
  setup.program = program.c_str();
  setup.argv = args.data();
  setup.envp = environ;
  setup.stdin_fd = null_input.fd;
  setup.output_fd = log.fd;
  setup.parent = ::getpid();
  Timer timer;
  const pid_t pid = spawn_child(setup, child_stack.get());
  const int spawn_errno = errno;
  null_input.reset(-1);
  log.reset(-1);
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
