#include "visloc/util/file_io.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>

#include "visloc/util/error.h"

namespace visloc {

AtomicFileWriter::AtomicFileWriter(std::filesystem::path target) : target_(std::move(target)) {
  // A unique temporary name beside the target (mkstemp: O_EXCL), so that
  // threads, processes and other hosts writing the same target never share it.
  std::string name = target_.string() + ".tmp.XXXXXX";
  fd_ = ::mkostemp(name.data(), O_CLOEXEC);
  temp_ = name;
  if (fd_ < 0)
    throw_error(ErrorCode::kIo, "cannot create a temporary file beside ", target_.string(), ": ", std::strerror(errno));
  ::fchmod(fd_, 0644);
}

AtomicFileWriter::~AtomicFileWriter() {
  if (fd_ >= 0) ::close(fd_);
  if (!committed_) {
    std::error_code ignored;
    std::filesystem::remove(temp_, ignored);
  }
}

void AtomicFileWriter::write(const void* data, size_t size) {
  const auto* p = static_cast<const char*>(data);
  size_t left = size;
  while (left > 0) {
    ssize_t n = ::write(fd_, p, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw_error(ErrorCode::kIo, "cannot write ", temp_.string(), ": ", std::strerror(errno));
    }
    p += n;
    left -= static_cast<size_t>(n);
  }
  offset_ += size;
}

void AtomicFileWriter::pad_to(size_t alignment) {
  static const char zeros[256] = {};
  while (offset_ % alignment != 0) {
    size_t n = std::min<size_t>(alignment - offset_ % alignment, sizeof(zeros));
    write(zeros, n);
  }
}

void AtomicFileWriter::write_at(uint64_t at, const void* data, size_t size) {
  if (::pwrite(fd_, data, size, static_cast<off_t>(at)) != static_cast<ssize_t>(size))
    throw_error(ErrorCode::kIo, "cannot write ", temp_.string(), ": ", std::strerror(errno));
}

void AtomicFileWriter::commit() {
  if (::fsync(fd_) != 0)
    throw_error(ErrorCode::kIo, "cannot sync ", temp_.string(), ": ", std::strerror(errno));
  if (::close(fd_) != 0) {
    fd_ = -1;
    throw_error(ErrorCode::kIo, "cannot close ", temp_.string(), ": ", std::strerror(errno));
  }
  fd_ = -1;
  std::error_code ec;
  std::filesystem::rename(temp_, target_, ec);
  if (ec)
    throw_error(ErrorCode::kIo, "cannot rename ", temp_.string(), " to ", target_.string(), ": ",
                ec.message());
  committed_ = true;
}

void write_file_atomic(const std::filesystem::path& path, std::string_view content) {
  AtomicFileWriter writer(path);
  writer.write(content);
  writer.commit();
}

void require_regular_file(const std::filesystem::path& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0)
    throw_error(ErrorCode::kIo, "cannot open ", path.string(), ": ", std::strerror(errno));
  if (!S_ISREG(st.st_mode))
    throw_error(ErrorCode::kIo, path.string(), " is not a regular file (a ",
                S_ISDIR(st.st_mode) ? "directory" : S_ISFIFO(st.st_mode) ? "FIFO" : "special file", ")");
}

std::string read_file(const std::filesystem::path& path) {
  // O_NONBLOCK: opening a FIFO must not wait for a writer; fstat then rejects
  // anything but a regular file.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) throw_error(ErrorCode::kIo, "cannot open ", path.string(), ": ", std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    require_regular_file(path);  // names what it is
    throw_error(ErrorCode::kIo, path.string(), " is not a regular file");
  }
  std::string out;
  out.reserve(static_cast<size_t>(st.st_size));
  char buf[1 << 16];
  for (;;) {
    const ssize_t got = ::read(fd, buf, sizeof(buf));
    if (got == 0) break;
    if (got < 0) {
      if (errno == EINTR) continue;
      const int e = errno;
      ::close(fd);
      throw_error(ErrorCode::kIo, "cannot read ", path.string(), ": ", std::strerror(e));
    }
    out.append(buf, static_cast<size_t>(got));
  }
  ::close(fd);
  return out;
}

}  // namespace visloc
