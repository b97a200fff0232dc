// Fuzzes the map manifest (map/map.h read_manifest), then opens the map the
// way a user does (Map::open, map_info, every segment, the descriptor files)
// on a copy of the reference map whose manifest.json is the input and whose
// other files are the real ones.
#include "fuzz_harness.h"
#include "visloc/map/map.h"

using namespace visloc;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::filesystem::path dir = fuzz::scratch_copy_of_reference("map");
  fuzz::write_scratch_file("map/manifest.json", data, size);
  if (!fuzz::accepts([&] { (void)read_manifest(dir).to_json().dump(); })) return 0;
  fuzz::accepts([&] {
    const MapInfo info = map_info(dir);
    (void)info.to_json().dump();
    const Map map = Map::open(dir);
    for (size_t i = 0; i < map.manifest().segments.size(); ++i) {
      const auto& entry = map.manifest().segments[i];
      if (map.open_segment(i)->num_points() != entry.points)
        fuzz::report_bug("an opened segment disagrees with its manifest entry", entry.file);
      if (!entry.descriptors_file.empty()) (void)read_point_descriptor_file(dir / entry.descriptors_file);
    }
  });
  return 0;
}
