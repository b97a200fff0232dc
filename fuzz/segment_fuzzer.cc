// Fuzzes segment files (map/segment_file.h Segment::open, kind "SEGM"), then
// walks the points and images read and searches the segment with the
// cascade matcher (lookup tables, Hamming codes, PQ codes).
// Built twice: segment_fuzzer opens without a map hash rotation;
// segment_map_rotation_fuzzer (VISLOC_FUZZ_MAP_ROTATION) passes the
// reference map's hash_rotation.vlitq, as a map with a shared rotation does.
#include "fuzz_harness.h"
#include "visloc/map/segment_file.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/matching/pq_codebook.h"

using namespace visloc;

VISLOC_FUZZ_SECTION_FILE_MUTATOR()

namespace {
// The reference 32-byte codebook, read when a version-4 segment first needs
// it (a reference directory made before it existed serves the other inputs).
const PqCodebook& codebook32() {
  static const PqCodebook codebook = PqCodebook::read(fuzz::scratch_copy_of_reference("pq32_codebook.vlpq"));
  return codebook;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const PqCodebook codebook = PqCodebook::read(fuzz::scratch_copy_of_reference("map/pq_codebook.vlpq"));

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
      CascadeMatcher matcher(segment->index(), segment->index().pq_subvectors == 32 ? codebook32() : codebook);
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
