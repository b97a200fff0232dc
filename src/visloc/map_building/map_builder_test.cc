#include <gtest/gtest.h>

#include <filesystem>

#include "visloc/map_building/map_builder.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

TEST(MapBuildOptions, RejectsBadInputsNamingThem) {
  MapBuildOptions o;
  try {
    o.validate();
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("--images"), std::string::npos) << e.what();
  }
  o.images_dir = "/nonexistent/images";
  try {
    o.validate();
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/images"), std::string::npos) << e.what();
  }
  o.images_dir = fs::temp_directory_path();
  o.poses = PoseSource::kKnown;
  EXPECT_THROW(o.validate(), Error);
  o.poses = PoseSource::kSfm;
  o.jobs = -1;
  EXPECT_THROW(o.validate(), Error);
}

// Without --hash-rotation a build keeps the existing map's rotation: a map
// made before the map-wide rotation became the default is not rebuilt (nor
// refused on update) for it; a new map gets one rotation.
TEST(MapBuildOptions, HashRotationDefaultsToTheExistingMaps) {
  const fs::path dir = unique_temp_dir("visloc_hash_rotation_default");
  EXPECT_EQ(resolve_hash_rotation(dir, std::nullopt), HashRotationScope::kMap);
  write_file_atomic(dir / "manifest.json", "{}");
  EXPECT_EQ(resolve_hash_rotation(dir, std::nullopt), HashRotationScope::kSegment);
  EXPECT_EQ(resolve_hash_rotation(dir, HashRotationScope::kMap), HashRotationScope::kMap);
  write_file_atomic(dir / kHashRotationFileName, "x");
  EXPECT_EQ(resolve_hash_rotation(dir, std::nullopt), HashRotationScope::kMap);
  EXPECT_EQ(resolve_hash_rotation(dir, HashRotationScope::kSegment), HashRotationScope::kSegment);
  fs::remove_all(dir);
}
