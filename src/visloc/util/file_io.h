// Files we write appear whole or not at all: AtomicFileWriter writes to a
// temporary name beside the target, fsyncs, and renames on commit(). If it is
// destroyed without commit() (an exception, a crash) the temporary is removed
// and the target is left as it was.
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace visloc {

class AtomicFileWriter {
 public:
  explicit AtomicFileWriter(std::filesystem::path target);
  ~AtomicFileWriter();
  AtomicFileWriter(const AtomicFileWriter&) = delete;
  AtomicFileWriter& operator=(const AtomicFileWriter&) = delete;

  void write(const void* data, size_t size);
  void write(std::string_view text) { write(text.data(), text.size()); }
  // Pads with zero bytes up to a multiple of `alignment` (file offset).
  void pad_to(size_t alignment);
  uint64_t offset() const { return offset_; }
  // Overwrites bytes already written at `at` (for headers written last).
  void write_at(uint64_t at, const void* data, size_t size);
  // Flushes, fsyncs and renames the temporary onto the target.
  void commit();

  const std::filesystem::path& target() const { return target_; }

 private:
  std::filesystem::path target_;
  std::filesystem::path temp_;
  int fd_ = -1;
  uint64_t offset_ = 0;
  bool committed_ = false;
};

// Convenience: writes the whole content atomically.
void write_file_atomic(const std::filesystem::path& path, std::string_view content);

// Throws Error(kIo) naming the file unless it is a regular file (a FIFO, a
// device or a directory would hang or mislead a reader).
void require_regular_file(const std::filesystem::path& path);

// Reads a whole regular file; throws Error(kIo) naming the file on failure.
std::string read_file(const std::filesystem::path& path);

}  // namespace visloc
