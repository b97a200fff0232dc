// Fuzzes COLMAP SQLite databases (colmap/colmap_database.h ColmapDatabase):
// opening (schema check), then every query: cameras, images, image_by_name,
// keypoints, descriptors, features and verified matches (bounded loops).
#include "fuzz_harness.h"
#include "visloc/colmap/colmap_database.h"

using namespace visloc;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::write_scratch_file("database.db", data, size);
  fuzz::accepts([&] {
    const ColmapDatabase db(path);
    uint64_t sum = 0;
    for (const ColmapDbCamera& c : db.cameras()) sum += c.params.size();
    const std::vector<ColmapDbImage> images = db.images();
    const size_t n = std::min<size_t>(images.size(), 8);
    for (size_t i = 0; i < n; ++i) {
      // A corrupted file's name index may disagree with its table: a miss is not a bug.
      fuzz::accepts([&] { sum += db.image_by_name(images[i].name).has_value(); });
      fuzz::accepts([&] { sum += db.keypoints(images[i].image_id).size(); });
      fuzz::accepts([&] { sum += db.descriptors(images[i].image_id).rows(); });
      fuzz::accepts([&] { sum += db.features(images[i].image_id).size(); });
      if (i > 0) fuzz::accepts([&] { sum += db.verified_matches(images[i - 1].image_id, images[i].image_id).size(); });
      if (i > 0) fuzz::accepts([&] { sum += db.verified_matches(images[i].image_id, images[0].image_id).size(); });
    }
    if (sum == 0xdeadbeef) std::fputc('.', stderr);
  });
  return 0;
}
