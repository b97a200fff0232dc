// Bundler reconstructions, as the benchmark datasets of the field are
// distributed (Dubrovnik, Rome, Vienna, Aachen): bundle.out (Bundler v0.3),
// the image list, and Lowe's SIFT key files. Read here and converted to our
// ColmapModel so that the COLMAP import's pipeline (holdout, mean descriptor
// per point, compression) applies unchanged.
//
// bundle.out (Snavely's "Bundler v0.3 user's manual"):
//   # Bundle file v0.3
//   <num_cameras> <num_points>
//   per camera:  f k1 k2 / R (3 rows) / t        (f = 0: camera not registered)
//   per point:   X Y Z / r g b / n (camera key x y)×n
// A world point X is seen at P = R X + t in a camera frame that looks down
// −z with +y up; its projection is p = −P/P.z, distorted by
// 1 + k1|p|² + k2|p|⁴ and scaled by f. The views' (x, y) are pixels relative
// to the image centre, x right, y UP; `key` is the index of the keypoint in
// the image's key file.
//
// List file: one line per camera of bundle.out, in order: "name [0 focal]".
//
// Lowe's key files (.key, or gzip .key.gz): "N 128", then per keypoint
// "row col scale orientation" and 128 integers 0..255 (over several lines):
// the SIFT vector L2-normalized, clamped at 0.2, renormalized, × 512.
//
// Conversion (documented in docs/formats.md, "Bundler import"):
//   cam_from_world = diag(1, −1, −1) · [R | t] (COLMAP's camera looks down +z,
//   y down); camera model RADIAL (f, cx, cy, k1, k2), one camera per image;
//   COLMAP pixel of a view = (cx + x, cy − y); principal point = image centre
//   (w/2, h/2) in COLMAP's convention (top-left pixel centre at (0.5, 0.5))
//   when image sizes are known, else derived from the key files: a key at
//   (row, col) — pixel indices, top-left pixel centre at (0, 0), as Lowe's
//   and Bundler's code use them — is at COLMAP pixel (col + 0.5, row + 0.5),
//   and Bundler centred it as x = col − (w − 1)/2, y = (h − 1)/2 − row, so
//   cx = col + 0.5 − x = w/2 and cy = row + 0.5 + y = h/2 (the median over
//   the image's views is used). The i-th 2D point of an image is the i-th
//   key of its key file (COLMAP's "i-th keypoint" convention).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "visloc/colmap/colmap_model.h"
#include "visloc/features/feature_set.h"

namespace visloc {

// ---------------------------------------------------------------- bundle.out
struct BundlerCamera {
  double focal = 0, k1 = 0, k2 = 0;
  std::array<double, 9> rotation{};     // Bundler's R, row-major (camera looks down −z, y up)
  std::array<double, 3> translation{};  // Bundler's t
  uint64_t line = 0;                    // line of "f k1 k2" in bundle.out
  bool registered() const { return focal != 0; }
};

struct BundlerView {
  uint32_t camera = 0;  // index into the cameras (= line of the list file)
  uint32_t key = 0;     // index into that image's key file
  double x = 0, y = 0;  // pixels from the image centre, x right, y up
};

struct BundlerPoint {
  std::array<double, 3> xyz{0, 0, 0};
  std::array<uint8_t, 3> rgb{0, 0, 0};
  std::vector<BundlerView> views;
  uint64_t line = 0;  // line of the view list in bundle.out (for error messages)
};

struct BundlerFile {
  std::vector<BundlerCamera> cameras;
  std::vector<BundlerPoint> points;
};

// Reads bundle.out (plain or gzip). Throws Error(kIo) when it cannot be read
// and Error(kFormat) naming the file and line for a bad header, a truncated
// file, a bad number, a view naming a camera out of range, or trailing data.
BundlerFile read_bundler_file(const std::filesystem::path& path);

// ----------------------------------------------------------------- list file
struct BundlerListEntry {
  std::string name;        // image path as written (relative to the list's folder)
  bool has_focal = false;  // "name 0 focal": Bundler's initial focal estimate
  double focal = 0;
};
// Blank lines are skipped only at the end (a blank line inside would shift
// the camera numbering and is an error naming the line).
std::vector<BundlerListEntry> read_bundler_list(const std::filesystem::path& path);

// ---------------------------------------------------------------- key files
// Lowe's key file (plain or gzip, detected from the content) as a FeatureSet:
// keypoint x = col + 0.5, y = row + 0.5 (our pixel convention, the centre of
// the top-left pixel at (0.5, 0.5), like our SIFT's keypoints), scale = Lowe's
// scale (σ in pixels), orientation = −Lowe's orientation (Lowe measures it
// towards −y; OpenCV, COLMAP and our features towards +y, image y down).
// Descriptors: root_sift (default) converts them exactly as our extractor
// quantizes RootSIFT (sift_to_uint8: L1-normalize, square root, round(512 ·),
// clamp 255), so they match our query features and COLMAP's; otherwise
// Lowe's integers are kept as they are (L2 SIFT × 512, like COLMAP's
// L2 option). Lowe's and COLMAP's descriptors share the bin layout. image is
// the key file's name without ".key"/".key.gz"; image size 0 (unknown).
// Throws Error naming the file and line: bad header (not "N 128"), truncated
// file, a value outside 0..255, data after the N-th keypoint.
FeatureSet read_lowe_key_file(const std::filesystem::path& path, bool root_sift = true);

// Lowe's integer descriptor (0..255) → our uint8 RootSIFT (sift_to_uint8).
void lowe_descriptor_to_root_sift(const uint8_t* lowe, uint8_t* out);

// The key file of a listed image: with keys_dir empty, next to the image
// (list folder / name with its extension replaced by ".key", then
// ".key.gz"); otherwise keys_dir / name with that extension, then keys_dir /
// the file name alone. Throws Error(kNotFound) naming the paths tried.
std::filesystem::path find_lowe_key_file(const std::filesystem::path& list_dir, const std::filesystem::path& keys_dir,
                                         const std::string& image_name);

// ---------------------------------------------------------------- conversion
struct BundlerConversionOptions {
  std::filesystem::path keys_dir;    // empty: key files next to the listed images
  std::filesystem::path images_dir;  // non-empty: principal point from the images' sizes (read
                                     // from their headers); empty: derived from the key files
  bool root_sift = true;             // descriptors(): RootSIFT (our and COLMAP's default) or Lowe's raw
  double max_key_offset_px = 1.0;    // a view farther than this from its key counts as off its key
  void validate() const;
};

struct BundlerConversionStats {
  size_t cameras = 0;                   // in bundle.out
  size_t cameras_unregistered = 0;      // f = 0: dropped with their observations
  size_t images = 0;                    // registered images in the model
  size_t images_dropped_no_principal_point = 0;  // registered, no observation and no --images
  size_t points_read = 0;
  size_t points = 0;                    // with at least one observation left
  size_t observations = 0;
  size_t observations_dropped = 0;      // views of unregistered cameras
  size_t observations_off_key = 0;      // farther than max_key_offset_px from their key
  size_t keys = 0;                      // keypoints in the key files read
  std::string principal_point;          // "image size" or "key files"
  double ms_bundle = 0, ms_keys = 0;
};

struct BundlerModel {
  ColmapModel model;  // image_id = list line + 1; camera_id = image_id (one RADIAL camera per image)
  std::vector<std::filesystem::path> key_files;  // by image_id − 1 (empty for unregistered cameras)
  bool root_sift = true;
  BundlerConversionStats stats;

  // The descriptors of an image of `model`, from its key file: row i is the
  // i-th key, i.e. the i-th 2D point (an ImageDescriptorSource).
  DescriptorMatrix descriptors(const ColmapImage& image) const;
};

// Reads bundle.out, the list and every registered image's key file (to check
// the views' key indices, count the keys, fill the 2D points and, without
// images_dir, derive the principal point). Observed 2D points are the views'
// positions in COLMAP pixels; the other keys' 2D points are their key file
// positions. Points left without a view are dropped, as are registered images
// that cannot get a principal point (no image size and no view). Errors name
// the file and line: counts that do not match the list, a view naming a key
// beyond its key file, a rotation that is not one, missing key files/images.
BundlerModel read_bundler_model(const std::filesystem::path& bundle_file, const std::filesystem::path& list_file,
                                const BundlerConversionOptions& options = {});

}  // namespace visloc
