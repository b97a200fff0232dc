#include "visloc/util/section_file.h"

#include <algorithm>
#include <cstring>

#include "visloc/util/crc32c.h"

namespace visloc {
namespace {

std::string tag_string(const char (&tag)[8]) {
  return std::string(tag, strnlen(tag, sizeof(tag)));
}

std::string printable(std::string_view s) {
  std::string out;
  for (char c : s) out += (c >= 32 && c < 127) ? c : '?';
  return out;
}

}  // namespace

SectionFileWriter::SectionFileWriter(const std::filesystem::path& path, std::string_view kind,
                                     uint32_t kind_version)
    : out_(path) {
  VISLOC_CHECK(kind.size() == 4, "kind must be a fourcc");
  std::memcpy(header_.magic, "VLOC", 4);
  std::memcpy(header_.kind, kind.data(), 4);
  header_.container_version = kSectionFileVersion;
  header_.kind_version = kind_version;
  out_.write(&header_, sizeof(header_));  // placeholder, rewritten in commit()
}

void SectionFileWriter::add(std::string_view tag, const void* data, size_t size) {
  VISLOC_CHECK(!tag.empty() && tag.size() <= 8, "section tag must have 1-8 characters");
  for (const auto& e : entries_)
    VISLOC_CHECK(tag_string(e.tag) != tag, "duplicate section tag");
  out_.pad_to(kSectionAlignment);
  SectionEntry entry{};
  std::memcpy(entry.tag, tag.data(), tag.size());
  entry.offset = out_.offset();
  entry.size = size;
  entry.crc32c = crc32c(data, size);
  if (size > 0) out_.write(data, size);
  entries_.push_back(entry);
}

void SectionFileWriter::commit() {
  out_.pad_to(kSectionAlignment);
  header_.section_count = static_cast<uint32_t>(entries_.size());
  header_.table_offset = out_.offset();
  header_.table_crc32c = crc32c(entries_.data(), entries_.size() * sizeof(SectionEntry));
  out_.write(entries_.data(), entries_.size() * sizeof(SectionEntry));
  header_.file_size = out_.offset();
  header_.header_crc32c = crc32c(&header_, offsetof(SectionFileHeader, header_crc32c));
  out_.write_at(0, &header_, sizeof(header_));
  out_.commit();
}

SectionFileReader::SectionFileReader(const std::filesystem::path& path, std::string_view kind,
                                     uint32_t min_kind_version, uint32_t max_kind_version,
                                     Options options)
    : file_(path) {
  const std::string name = path.string();
  auto fail = [&](const auto&... parts) { throw_error(ErrorCode::kFormat, name, ": ", parts...); };
  if (file_.size() < sizeof(SectionFileHeader))
    fail("file is ", file_.size(), " bytes, too short for a visloc file header (truncated?)");
  std::memcpy(&header_, file_.data(), sizeof(header_));
  if (std::memcmp(header_.magic, "VLOC", 4) != 0) fail("not a visloc file (bad magic)");
  if (header_.header_crc32c != crc32c(&header_, offsetof(SectionFileHeader, header_crc32c)))
    fail("header checksum mismatch (corrupted)");
  if (std::memcmp(header_.kind, kind.data(), 4) != 0)
    fail("is a '", printable({header_.kind, 4}), "' file, expected '", kind, "'");
  if (header_.container_version != kSectionFileVersion)
    fail("container version ", header_.container_version, " is not supported (this build reads ",
         kSectionFileVersion, ")");
  if (header_.kind_version < min_kind_version || header_.kind_version > max_kind_version)
    fail("format version ", header_.kind_version, " is not supported (this build reads ",
         min_kind_version, "-", max_kind_version, ")");
  if (header_.file_size != file_.size())
    fail("file is ", file_.size(), " bytes but its header says ", header_.file_size,
         " (truncated or appended to)");
  const uint64_t table_bytes = uint64_t{header_.section_count} * sizeof(SectionEntry);
  if (header_.table_offset < sizeof(SectionFileHeader) || header_.table_offset > file_.size() ||
      table_bytes > file_.size() - header_.table_offset)
    fail("section table lies outside the file");
  entries_.resize(header_.section_count);
  if (table_bytes > 0) std::memcpy(entries_.data(), file_.data() + header_.table_offset, table_bytes);
  if (crc32c(entries_.data(), table_bytes) != header_.table_crc32c)
    fail("section table checksum mismatch (corrupted)");
  for (const auto& e : entries_) {
    if (e.offset % kSectionAlignment != 0 || e.offset < sizeof(SectionFileHeader) ||
        e.offset > header_.table_offset || e.size > header_.table_offset - e.offset)
      fail("section '", printable(tag_string(e.tag)), "' lies outside the file");
    if (options.verify_checksums && crc32c(file_.data() + e.offset, e.size) != e.crc32c)
      fail("section '", printable(tag_string(e.tag)), "' checksum mismatch (corrupted)");
  }
}

const SectionEntry* SectionFileReader::find(std::string_view tag) const {
  for (const auto& e : entries_)
    if (tag_string(e.tag) == tag) return &e;
  return nullptr;
}

bool SectionFileReader::has(std::string_view tag) const { return find(tag) != nullptr; }

std::span<const uint8_t> SectionFileReader::bytes(std::string_view tag) const {
  const SectionEntry* e = find(tag);
  if (e == nullptr)
    throw_error(ErrorCode::kFormat, path().string(), ": missing section '", tag, "'");
  return {file_.data() + e->offset, e->size};
}

std::string_view SectionFileReader::text(std::string_view tag) const {
  auto b = bytes(tag);
  return {reinterpret_cast<const char*>(b.data()), b.size()};
}

}  // namespace visloc
