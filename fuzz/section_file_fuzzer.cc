// Fuzzes the section-file container (util/section_file.h SectionFileReader)
// with whatever kind the input names: header, table, bounds and CRC checks,
// then every section through bytes(), text() and typed array views.
#include "fuzz_harness.h"

using namespace visloc;

VISLOC_FUZZ_SECTION_FILE_MUTATOR()

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("file.vloc", data, size);
  // The kind the file claims, so that any kind reaches the later checks.
  std::string kind = "FEAT";
  if (size >= 8) kind.assign(reinterpret_cast<const char*>(data) + 4, 4);
  for (const bool verify : {true, false}) {
    fuzz::accepts([&] {
      SectionFileReader reader(path, kind, 0, UINT32_MAX, {.verify_checksums = verify});
      uint64_t sum = reader.kind_version() + reader.file_size();
      for (const SectionEntry& e : reader.sections()) {
        const std::string tag(e.tag, strnlen(e.tag, sizeof(e.tag)));
        if (!reader.has(tag)) fuzz::report_bug("has() denies a listed section", tag);
        for (uint8_t b : reader.bytes(tag)) sum += b;
        sum += reader.text(tag).size();
        fuzz::accepts([&] { sum += reader.array<uint64_t>(tag).size(); });
        fuzz::accepts([&] { sum += reader.array<float>(tag, 16).size(); });
      }
      if (sum == 0xdeadbeef) std::fputc('.', stderr);  // keeps the reads alive
    });
  }
  return 0;
}
