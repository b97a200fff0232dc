#include <gtest/gtest.h>

#include <filesystem>

#include "visloc/map_building/map_builder.h"
#include "visloc/util/error.h"

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
