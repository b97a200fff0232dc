// Fuzzes a retrieval map (retrieval/retrieval_map.h RetrievalMap::load) one
// file at a time: the input's section-file kind picks the file it replaces
// (RIMG images.vlimg, IIDX index.vlidx, TEMB embedding.vltemb; anything else
// images.vlimg), the other two are the reference map's real files. Then
// queries the map and walks its image table.
#include <array>

#include "fuzz_harness.h"
#include "visloc/retrieval/retrieval_map.h"
#include "visloc/util/file_io.h"

using namespace visloc;

VISLOC_FUZZ_SECTION_FILE_MUTATOR()

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::array<std::string, 3> names = {"images.vlimg", "index.vlidx", "embedding.vltemb"};
  static const std::filesystem::path dir = fuzz::scratch_copy_of_reference("map/retrieval");
  static const std::array<std::string, 3> valid = {read_file(dir / names[0]), read_file(dir / names[1]),
                                                   read_file(dir / names[2])};
  static const DescriptorMatrix descriptors = fuzz::sample_descriptors(16);
  const std::string_view kind = size >= 8 ? std::string_view(reinterpret_cast<const char*>(data) + 4, 4) : "";
  const size_t which = kind == "IIDX" ? 1 : kind == "TEMB" ? 2 : 0;
  fuzz::write_scratch_file("map/retrieval/" + names[which], data, size);
  fuzz::accepts([&] {
    const RetrievalMap map = RetrievalMap::load(dir);
    const SegmentTable& table = map.segments();
    uint64_t sum = 0;
    for (size_t i = 0; i < table.image_count(); ++i)
      for (int32_t s : table.segments(i)) sum += uint32_t(s);
    for (const auto& name : map.image_names()) sum += name.size();
    const RetrievalQueryResult r = map.query(descriptors, SegmentVoterOptions{});
    for (const auto& image : r.images)
      if (image.image >= 0 && size_t(image.image) >= map.image_names().size())
        fuzz::report_bug("a query succeeded with an image outside the image table", std::to_string(image.image));
    if (sum == 0xdeadbeef) std::fputc('.', stderr);
  });
  const std::string& original = valid[which];
  fuzz::write_scratch_file("map/retrieval/" + names[which], reinterpret_cast<const uint8_t*>(original.data()),
                           original.size());
  return 0;
}
