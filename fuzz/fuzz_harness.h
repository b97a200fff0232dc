// Shared harness of the libFuzzer targets in fuzz/: a private scratch
// directory per process, writing an input to a named file there, the
// exception policy (a visloc::Error with a user-facing code is the expected
// rejection; anything else is a bug and traps), the reference files copied
// from a small real map or model, and a structure-aware mutator for the
// visloc section files (util/section_file.h) that keeps their sizes and
// CRC32C checksums right so that mutations reach the payload parsers.
#pragma once

#include <cxxabi.h>
#include <stdlib.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <string_view>
#include <typeinfo>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/util/crc32c.h"
#include "visloc/util/error.h"
#include "visloc/util/section_file.h"

extern "C" size_t LLVMFuzzerMutate(uint8_t* data, size_t size, size_t max_size);

namespace visloc::fuzz {

// ------------------------------------------------------------------ failures

// Prints what went wrong and traps, so that libFuzzer saves the input.
[[noreturn]] inline void report_bug(std::string_view kind, std::string_view detail) {
  std::fprintf(stderr, "\n==visloc-fuzz== BUG: %.*s\n==visloc-fuzz== %.*s\n", int(kind.size()), kind.data(),
               int(detail.size()), detail.data());
  std::fflush(stderr);
  __builtin_trap();
}

inline std::string demangled(const char* name) {
  int status = 0;
  char* readable = abi::__cxa_demangle(name, nullptr, nullptr, &status);
  std::string out = status == 0 && readable ? readable : name;
  std::free(readable);
  return out;
}

// Runs `read` (a reader and its accessors). Returns true when it accepted the
// input, false when it rejected it with a visloc::Error of any code but
// kInternal. Anything else is a bug: kInternal (a VISLOC_CHECK failed), any
// other exception escaping (nlohmann::json, std::bad_alloc, std::out_of_range...).
template <typename Read>
bool accepts(Read&& read) {
  try {
    read();
    return true;
  } catch (const Error& e) {
    if (e.code() != ErrorCode::kInternal) return false;
    report_bug("visloc::Error with code kInternal (an invariant did not hold)", e.what());
  } catch (const std::exception& e) {
    report_bug(demangled(typeid(e).name()) + " escaped the reader", e.what());
  } catch (...) {
    const std::type_info* type = abi::__cxa_current_exception_type();
    report_bug((type ? demangled(type->name()) : std::string("an exception")) + " escaped the reader", "");
  }
}

// ----------------------------------------------------------------- the files

// The process's private scratch directory, created on first use (under
// $VISLOC_FUZZ_TMPDIR, else /dev/shm, else $TMPDIR or /tmp) and removed at exit.
inline const std::filesystem::path& scratch_dir() {
  // Never destroyed, so that the exit handler can still read it.
  static const std::filesystem::path* const dir = [] {
    std::string base = "/tmp";
    if (const char* t = std::getenv("TMPDIR"); t && *t) base = t;
    if (::access("/dev/shm", W_OK) == 0) base = "/dev/shm";
    if (const char* t = std::getenv("VISLOC_FUZZ_TMPDIR"); t && *t) base = t;
    std::string name = base + "/visloc-fuzz-XXXXXX";
    if (::mkdtemp(name.data()) == nullptr) report_bug("cannot create the scratch directory", name);
    auto* path = new std::filesystem::path(name);
    std::atexit([] {
      std::error_code ec;
      std::filesystem::remove_all(scratch_dir(), ec);
    });
    return path;
  }();
  return *dir;
}

// Writes `bytes` to scratch_dir() / relative (parents created) and returns its path.
inline std::filesystem::path write_scratch_file(const std::filesystem::path& relative, std::span<const uint8_t> bytes) {
  const std::filesystem::path path = scratch_dir() / relative;
  std::filesystem::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) report_bug("cannot write the input file", path.string());
  return path;
}

inline std::filesystem::path write_scratch_file(const std::filesystem::path& relative, const uint8_t* data,
                                                size_t size) {
  return write_scratch_file(relative, std::span<const uint8_t>(data, size));
}

// The reference files that some targets keep valid beside the fuzzed one:
// $VISLOC_FUZZ_REFERENCE, else the directory fuzz/make_seeds.sh fills in the
// fuzz build (VISLOC_FUZZ_DEFAULT_REFERENCE). Layout:
//   map/      a small real map (hash rotation "map", with retrieval/)
//   colmap/   a small real COLMAP model, binary and text
//   pq32_codebook.vlpq  a 32-byte PQ codebook (version-4 segments' searches)
inline std::filesystem::path reference_dir() {
  if (const char* r = std::getenv("VISLOC_FUZZ_REFERENCE"); r && *r) return r;
#ifdef VISLOC_FUZZ_DEFAULT_REFERENCE
  return VISLOC_FUZZ_DEFAULT_REFERENCE;
#else
  return "reference";
#endif
}

// Copies reference_dir() / relative into scratch_dir() / relative once per
// process (the readers only read it) and returns the copy's path. Exits with
// a clear message when the reference is missing: run fuzz/make_seeds.sh.
inline std::filesystem::path scratch_copy_of_reference(const std::filesystem::path& relative) {
  const std::filesystem::path from = reference_dir() / relative, to = scratch_dir() / relative;
  if (!std::filesystem::exists(from)) {
    std::fprintf(stderr,
                 "visloc fuzz: reference %s is missing; set VISLOC_FUZZ_REFERENCE to the reference/ folder that "
                 "fuzz/make_seeds.sh makes\n",
                 from.c_str());
    std::exit(2);
  }
  if (!std::filesystem::exists(to)) {
    std::filesystem::create_directories(to.parent_path());
    std::filesystem::copy(from, to, std::filesystem::copy_options::recursive);
  }
  return to;
}

// Deterministic SIFT-like query descriptors for the accessors that search
// what was read (the same every run, so that a crash reproduces).
inline DescriptorMatrix sample_descriptors(size_t rows) {
  DescriptorMatrix d(rows);
  std::minstd_rand random(7);
  for (size_t i = 0; i < d.size_bytes(); ++i) d.data()[i] = static_cast<uint8_t>(random() % 64);
  return d;
}

// --------------------------------------------------- section-file mutation

struct SectionFileImage {
  SectionFileHeader header{};
  std::vector<std::pair<std::string, std::vector<uint8_t>>> sections;  // tag, payload
};

// Reads a section file's structure without checking CRCs (nullopt when its
// header or table cannot be located).
inline std::optional<SectionFileImage> parse_section_file(std::span<const uint8_t> file) {
  SectionFileImage image;
  if (file.size() < sizeof(SectionFileHeader)) return std::nullopt;
  std::memcpy(&image.header, file.data(), sizeof(SectionFileHeader));
  const uint64_t table = image.header.table_offset, count = image.header.section_count;
  if (std::memcmp(image.header.magic, "VLOC", 4) != 0 || count > 64 || table > file.size() ||
      count * sizeof(SectionEntry) > file.size() - table)
    return std::nullopt;
  for (uint64_t i = 0; i < count; ++i) {
    SectionEntry e;
    std::memcpy(&e, file.data() + table + i * sizeof(SectionEntry), sizeof(e));
    if (e.offset > file.size() || e.size > file.size() - e.offset) return std::nullopt;
    image.sections.emplace_back(std::string(e.tag, strnlen(e.tag, sizeof(e.tag))),
                                std::vector<uint8_t>(file.data() + e.offset, file.data() + e.offset + e.size));
  }
  return image;
}

// Lays the sections out as SectionFileWriter does, with every size and CRC right.
inline std::vector<uint8_t> serialize_section_file(const SectionFileImage& image) {
  auto pad = [](std::vector<uint8_t>& out) { out.resize((out.size() + kSectionAlignment - 1) / kSectionAlignment * kSectionAlignment); };
  std::vector<uint8_t> out(sizeof(SectionFileHeader));
  std::vector<SectionEntry> entries;
  for (const auto& [tag, payload] : image.sections) {
    pad(out);
    SectionEntry e{};
    std::memcpy(e.tag, tag.data(), std::min(tag.size(), sizeof(e.tag)));
    e.offset = out.size();
    e.size = payload.size();
    e.crc32c = crc32c(payload.data(), payload.size());
    out.insert(out.end(), payload.begin(), payload.end());
    entries.push_back(e);
  }
  pad(out);
  SectionFileHeader h = image.header;
  h.section_count = static_cast<uint32_t>(entries.size());
  h.table_offset = out.size();
  h.table_crc32c = crc32c(entries.data(), entries.size() * sizeof(SectionEntry));
  const auto* table = reinterpret_cast<const uint8_t*>(entries.data());
  out.insert(out.end(), table, table + entries.size() * sizeof(SectionEntry));
  h.file_size = out.size();
  h.header_crc32c = crc32c(&h, offsetof(SectionFileHeader, header_crc32c));
  std::memcpy(out.data(), &h, sizeof(h));
  return out;
}

// Makes the recorded file size and every checksum that can be computed
// (sections inside the file, the table, the header) agree with the bytes.
inline void repair_section_file(uint8_t* data, size_t size) {
  if (size < sizeof(SectionFileHeader) || std::memcmp(data, "VLOC", 4) != 0) return;
  SectionFileHeader h;
  std::memcpy(&h, data, sizeof(h));
  h.file_size = size;
  const uint64_t table = h.table_offset, count = h.section_count;
  if (table >= sizeof(SectionFileHeader) && table <= size && count <= (size - table) / sizeof(SectionEntry)) {
    for (uint64_t i = 0; i < count; ++i) {
      uint8_t* at = data + table + i * sizeof(SectionEntry);
      SectionEntry e;
      std::memcpy(&e, at, sizeof(e));
      if (e.offset <= size && e.size <= size - e.offset) e.crc32c = crc32c(data + e.offset, e.size);
      std::memcpy(at, &e, sizeof(e));
    }
    h.table_crc32c = crc32c(data + table, count * sizeof(SectionEntry));
  }
  h.header_crc32c = crc32c(&h, offsetof(SectionFileHeader, header_crc32c));
  std::memcpy(data, &h, sizeof(h));
}

// The custom mutator of the section-file targets: half the time one section's
// payload is mutated (it may grow or shrink) and the file re-laid out; else
// the whole file is mutated as bytes and, 9 times in 10, its sizes and
// checksums are repaired (the rest keep exercising the integrity checks).
inline size_t mutate_section_file(uint8_t* data, size_t size, size_t max_size, unsigned int seed) {
  std::minstd_rand random(seed);
  const unsigned choice = random() % 10;
  if (choice < 5) {
    if (auto image = parse_section_file({data, size}); image && !image->sections.empty()) {
      auto& payload = image->sections[random() % image->sections.size()].second;
      const size_t room = max_size > size ? std::min<size_t>(max_size - size, 4096) : 0;
      const size_t old_size = payload.size();
      // An empty payload with no room to grow (the file at max_size) is left
      // to the whole-file mutation: LLVMFuzzerMutate writes a byte even when
      // given no room, through the empty vector's null pointer (found by the
      // fuzzer itself, on a residual codebook seed as large as -max_len).
      if (old_size + room > 0) {
        payload.resize(old_size + room);
        payload.resize(LLVMFuzzerMutate(payload.data(), old_size, payload.size()));
        if (random() % 16 == 0) image->header.kind_version += (random() % 3) - 1;
        const std::vector<uint8_t> out = serialize_section_file(*image);
        if (out.size() <= max_size) {
          std::memcpy(data, out.data(), out.size());
          return out.size();
        }
      }
    }
  }
  const size_t n = LLVMFuzzerMutate(data, size, max_size);
  if (choice != 9) repair_section_file(data, n);
  return n;
}

}  // namespace visloc::fuzz

// Gives a target the section-file mutator.
#define VISLOC_FUZZ_SECTION_FILE_MUTATOR()                                                        \
  extern "C" size_t LLVMFuzzerCustomMutator(uint8_t* data, size_t size, size_t max_size,         \
                                            unsigned int seed) {                                 \
    return visloc::fuzz::mutate_section_file(data, size, max_size, seed);                        \
  }
