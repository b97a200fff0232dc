// Fuzzes segment files (map/segment_file.h Segment::open, kind "SEGM"), then
// walks the points and images read and searches the segment with the
// cascade matcher (lookup tables, Hamming codes, PQ codes).
// Built twice: segment_fuzzer opens without a map hash rotation;
// segment_map_rotation_fuzzer (VISLOC_FUZZ_MAP_ROTATION) passes the
// reference map's hash_rotation.vlitq, as a map with a shared rotation does.
#include <filesystem>
#include <optional>

#include "fuzz_harness.h"
#include "visloc/map/segment_file.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/matching/pq_codebook.h"

using namespace visloc;

VISLOC_FUZZ_SECTION_FILE_MUTATOR()

namespace {
// The reference 32-byte codebook, read once before any input (outside
// fuzz::accepts, so a damaged reference stops the run rather than passing
// for rejected inputs); absent from a reference directory made before it
// existed: version-4 segments are then opened and walked, not searched.
std::optional<PqCodebook> reference_codebook32() {
  const std::filesystem::path path = fuzz::reference_dir() / "pq32_codebook.vlpq";
  if (!std::filesystem::exists(path)) return std::nullopt;
  return PqCodebook::read(fuzz::scratch_copy_of_reference("pq32_codebook.vlpq"));
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const PqCodebook codebook = PqCodebook::read(fuzz::scratch_copy_of_reference("map/pq_codebook.vlpq"));
  static const std::optional<PqCodebook> codebook32 = reference_codebook32();

#ifdef VISLOC_FUZZ_MAP_ROTATION
  static const auto map_hasher = std::make_shared<const BinaryHasher>(
      read_hash_rotation_file(fuzz::scratch_copy_of_reference(std::string("map/") + kHashRotationFileName)));
#else
  static const std::shared_ptr<const BinaryHasher> map_hasher;
#endif
  static const DescriptorMatrix queries = fuzz::sample_descriptors(32);
  const auto path = fuzz::write_scratch_file("segments/0000.vlseg", data, size);
  fuzz::accepts([&] {
    const std::unique_ptr<Segment> segment = Segment::open(path, map_hasher);
    double sum = segment->id() + segment->format_version() + segment->bytes().other;
    for (float v : segment->xyz()) sum += v;
    for (const SegmentImage& image : segment->images()) sum += image.camera_params.size() + image.name.size();
    if (segment->enu_from_segment()) sum += segment->enu_from_segment()->scale;
    sum += double(segment->meta().dump().size());
    for (int radius : {0, 1}) {
      CascadeSearchOptions options;
      options.lut_radius = radius;
      const bool fine = segment->index().pq_subvectors == kPqFineSubvectors;
      if (fine && !codebook32) break;
      CascadeMatcher matcher(segment->index(), fine ? *codebook32 : codebook);
      const CascadeMatches matches = matcher.match(queries, options);
      for (uint32_t p : matches.point)
        if (p >= segment->num_points()) fuzz::report_bug("a match names a point outside the segment", std::to_string(p));
      for (uint32_t p : matches.many_points)
        if (p >= segment->num_points()) fuzz::report_bug("a 1-M match names a point outside the segment", std::to_string(p));
    }
    if (sum == 0.125) std::fputc('.', stderr);
  });
  return 0;
}
