// Fuzzes COLMAP sparse models (colmap/colmap_model.h), one file at a time:
// the first input byte picks cameras, images or points3D (modulo 3), the rest
// is that file; the other two are the reference model's real files. Built
// twice: colmap_binary_fuzzer (read_colmap_model_binary, *.bin) and
// colmap_text_fuzzer (VISLOC_FUZZ_COLMAP_TEXT: read_colmap_model_text, *.txt).
// A model read is walked, every track checked against its images as the
// reader promises.
#include <array>

#include "fuzz_harness.h"
#include "visloc/colmap/colmap_model.h"
#include "visloc/util/file_io.h"

using namespace visloc;

#ifdef VISLOC_FUZZ_COLMAP_TEXT
static constexpr const char* kExtension = ".txt";
static ColmapModel read_model(const std::filesystem::path& dir) { return read_colmap_model_text(dir); }
#else
static constexpr const char* kExtension = ".bin";
static ColmapModel read_model(const std::filesystem::path& dir) { return read_colmap_model_binary(dir); }
#endif

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::array<std::string, 3> names = {std::string("cameras") + kExtension,
                                                   std::string("images") + kExtension,
                                                   std::string("points3D") + kExtension};
  static const std::filesystem::path dir = [] {
    for (const auto& name : names) fuzz::scratch_copy_of_reference("colmap/" + name);
    return fuzz::scratch_dir() / "colmap";
  }();
  static const std::array<std::string, 3> valid = {read_file(dir / names[0]), read_file(dir / names[1]),
                                                   read_file(dir / names[2])};
  if (size == 0) return 0;
  const size_t which = data[0] % 3;
  fuzz::write_scratch_file("colmap/" + names[which], data + 1, size - 1);
  fuzz::accepts([&] {
    const ColmapModel model = read_model(dir);
    for (const ColmapCamera& c : model.cameras)
      if (!fuzz::accepts([&] { validate_colmap_camera(c, "camera read"); }))
        fuzz::report_bug("the reader returned a camera that validate_colmap_camera rejects", std::to_string(c.camera_id));
    for (const ColmapImage& image : model.images) {
      if (!fuzz::accepts([&] { validate_colmap_image_pose(image, "image read"); }))
        fuzz::report_bug("the reader returned an image that validate_colmap_image_pose rejects", image.name);
      (void)colmap_image_pose(image).center();
      if (model.camera_index(image.camera_id) < 0) fuzz::report_bug("an image names an absent camera", image.name);
      if (model.image_index(image.image_id) < 0 || model.image_index_by_name(image.name) < 0)
        fuzz::report_bug("an image read cannot be found", image.name);
      if (image.point3d_ids.size() != image.points2d.size())
        fuzz::report_bug("2D points and their 3D ids differ in count", image.name);
    }
    for (const ColmapPoint3D& p : model.points)
      for (const ColmapTrackElement& t : p.track) {
        const int64_t i = model.image_index(t.image_id);
        if (i < 0 || t.point2d_idx >= model.images[size_t(i)].points2d.size())
          fuzz::report_bug("a track names an absent image or 2D point", std::to_string(p.point3d_id));
      }
    (void)model.num_observations();
  });
  const auto& original = valid[which];
  fuzz::write_scratch_file("colmap/" + names[which], reinterpret_cast<const uint8_t*>(original.data()), original.size());
  return 0;
}
