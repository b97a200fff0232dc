// SectionFile: the container of every binary file visloc writes (feature
// files, segment files, retrieval parameters). Byte layout in docs/formats.md:
//
//   [0,64)   header: magic "VLOC", kind fourcc, container version, kind version,
//            section count, file size, table offset, table CRC32C, header CRC32C
//   ...      sections, each starting on a 64-byte boundary
//   table    section entries (tag[8], offset u64, size u64, crc32c u32, pad u32)
//
// All integers little-endian. A reader maps the file (no copy), checks the
// magic, kind, versions, that the recorded file size equals the real one
// (truncation), that every section lies inside the file, and every CRC.
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/mapped_file.h"

namespace visloc {

inline constexpr uint32_t kSectionFileVersion = 1;
inline constexpr size_t kSectionAlignment = 64;

struct SectionEntry {
  char tag[8];
  uint64_t offset;
  uint64_t size;
  uint32_t crc32c;
  uint32_t reserved;
};
static_assert(sizeof(SectionEntry) == 32);

struct SectionFileHeader {
  char magic[4];          // "VLOC"
  char kind[4];           // e.g. "FEAT", "SEGM"
  uint32_t container_version;
  uint32_t kind_version;  // schema version of the payload
  uint32_t section_count;
  uint32_t reserved0;
  uint64_t file_size;
  uint64_t table_offset;
  uint32_t table_crc32c;
  uint32_t reserved1;
  uint8_t reserved2[12];
  uint32_t header_crc32c;  // over bytes [0, 60)
};
static_assert(sizeof(SectionFileHeader) == 64);

class SectionFileWriter {
 public:
  SectionFileWriter(const std::filesystem::path& path, std::string_view kind, uint32_t kind_version);
  // Appends a section; tags are at most 8 characters and unique.
  void add(std::string_view tag, const void* data, size_t size);
  template <typename T>
  void add_array(std::string_view tag, std::span<const T> values) {
    add(tag, values.data(), values.size_bytes());
  }
  void add_text(std::string_view tag, std::string_view text) { add(tag, text.data(), text.size()); }
  // Writes the table and header, then renames into place.
  void commit();

 private:
  AtomicFileWriter out_;
  SectionFileHeader header_{};
  std::vector<SectionEntry> entries_;
};

class SectionFileReader {
 public:
  struct Options {
    bool verify_checksums = true;  // CRC of every section at open
  };
  // Opens and validates. `kind` must match; kind versions outside
  // [min_kind_version, max_kind_version] are rejected.
  SectionFileReader(const std::filesystem::path& path, std::string_view kind,
                    uint32_t min_kind_version, uint32_t max_kind_version, Options options);
  SectionFileReader(const std::filesystem::path& path, std::string_view kind,
                    uint32_t min_kind_version, uint32_t max_kind_version)
      : SectionFileReader(path, kind, min_kind_version, max_kind_version, Options{}) {}

  uint32_t kind_version() const { return header_.kind_version; }
  bool has(std::string_view tag) const;
  std::span<const uint8_t> bytes(std::string_view tag) const;
  std::string_view text(std::string_view tag) const;
  // A typed view; checks that the size is a multiple of sizeof(T) and, when
  // `expected_count` is given, equals it.
  template <typename T>
  std::span<const T> array(std::string_view tag, int64_t expected_count = -1) const {
    auto b = bytes(tag);
    if (b.size() % sizeof(T) != 0 ||
        (expected_count >= 0 && b.size() / sizeof(T) != static_cast<uint64_t>(expected_count)))
      throw_error(ErrorCode::kFormat, path().string(), ": section '", tag, "' has ", b.size(),
                  " bytes, expected ",
                  expected_count >= 0 ? std::to_string(expected_count) + " elements of "
                                      : std::string("a multiple of "),
                  sizeof(T), " bytes");
    return {reinterpret_cast<const T*>(b.data()), b.size() / sizeof(T)};
  }
  const std::filesystem::path& path() const { return file_.path(); }
  size_t file_size() const { return file_.size(); }
  const std::vector<SectionEntry>& sections() const { return entries_; }

 private:
  const SectionEntry* find(std::string_view tag) const;
  MappedFile file_;
  SectionFileHeader header_{};
  std::vector<SectionEntry> entries_;
};

}  // namespace visloc
