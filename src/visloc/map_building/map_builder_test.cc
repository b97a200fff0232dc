#include <gtest/gtest.h>

#include <filesystem>

#include "visloc/map_building/map_builder.h"
#include "visloc/matching/pq_codebook.h"
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

// The PQ code size of a build: the existing map's codebook's whatever
// pq.subvectors says; an explicit --pq-bytes unlike it is refused, naming the
// flag, before the build writes anything; a new map takes the explicit value,
// else pq.subvectors; an unreadable codebook is its reader's error.
TEST(MapBuildOptions, PqCodeBytesFollowTheExistingMapsCodebook) {
  const fs::path dir = unique_temp_dir("visloc_pq_code_bytes");
  MapBuildOptions o;
  o.images_dir = dir;
  EXPECT_EQ(resolve_pq_code_bytes(dir, o), 16);
  o.pq.subvectors = 32;
  EXPECT_EQ(resolve_pq_code_bytes(dir, o), 32);
  o.pq_code_bytes = 16;
  EXPECT_EQ(resolve_pq_code_bytes(dir, o), 16);
  std::vector<float> c(kPqCentroidFloats);
  for (size_t i = 0; i < c.size(); ++i) c[i] = float(i % 89);
  for (const int existing : {16, 32}) {
    PqCodebook(c, existing).write(dir / "pq_codebook.vlpq", "{}");
    for (const int subvectors : {16, 32}) {
      MapBuildOptions resumed;
      resumed.images_dir = dir;
      resumed.pq.subvectors = subvectors;
      EXPECT_EQ(resolve_pq_code_bytes(dir, resumed), existing);
      resumed.pq_code_bytes = subvectors;
      if (subvectors == existing) {
        EXPECT_EQ(resolve_pq_code_bytes(dir, resumed), existing);
        continue;
      }
      try {
        build_map(dir, resumed);
        ADD_FAILURE() << "an explicit " << subvectors << "-byte build of a " << existing << "-byte map";
      } catch (const Error& e) {
        EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument);
        EXPECT_NE(std::string(e.what()).find("--pq-bytes " + std::to_string(existing)), std::string::npos) << e.what();
      }
      EXPECT_FALSE(fs::exists(dir / "work")) << "the refused build wrote its work directory";
    }
  }
  write_file_atomic(dir / "pq_codebook.vlpq", "not a codebook");
  try {
    resolve_pq_code_bytes(dir, o);
    ADD_FAILURE() << "a damaged codebook read";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("pq_codebook.vlpq"), std::string::npos) << e.what();
  }
  o.pq_code_bytes = 24;
  EXPECT_THROW(o.validate(), Error);
  fs::remove_all(dir);
}

// Residual parts and beam likewise: a new map's from the options (explicit
// over pq's), an existing residual map's whatever pq says, an explicit value
// unlike its refused before the build writes anything; a product map ignores
// them.
TEST(MapBuildOptions, ResidualPartsAndBeamFollowTheExistingMapsCodebook) {
  const fs::path dir = unique_temp_dir("visloc_pq_residual");
  MapBuildOptions o;
  o.images_dir = dir;
  o.pq.residual_beam = 3;
  o.pq_residual_splits = 4;
  PqTrainingOptions pq;
  resolve_pq_residual(dir, o, pq);
  EXPECT_EQ(pq.residual_splits, 4);
  EXPECT_EQ(pq.residual_beam, 3);
  std::vector<float> product(kPqCentroidFloats), residual(size_t(16) * 256 * 128);
  for (size_t i = 0; i < product.size(); ++i) product[i] = float(i % 89);
  for (size_t i = 0; i < residual.size(); ++i) residual[i] = float(i % 97) - 40;
  PqCodebook(product).write(dir / "pq_codebook.vlpq", "{}");
  pq = {};
  resolve_pq_residual(dir, o, pq);  // a product map: nothing to follow or refuse
  EXPECT_EQ(pq.residual_splits, PqTrainingOptions{}.residual_splits);
  PqCodebook::residual(residual, 1, 7).write(dir / "pq_codebook.vlpq", "{}");
  MapBuildOptions resumed;
  resumed.images_dir = dir;
  resumed.pq.residual_splits = 2;
  resumed.pq.residual_beam = 5;
  resolve_pq_residual(dir, resumed, pq);
  EXPECT_EQ(pq.residual_splits, 1);
  EXPECT_EQ(pq.residual_beam, 7);
  resumed.pq_residual_splits = 1;
  resumed.pq_residual_beam = 7;
  EXPECT_NO_THROW(resolve_pq_residual(dir, resumed, pq));
  for (const char* flag : {"--pq-residual-splits 1", "--pq-residual-beam 7"}) {
    MapBuildOptions unlike = resumed;
    if (std::string(flag).find("splits") != std::string::npos)
      unlike.pq_residual_splits = 4;
    else
      unlike.pq_residual_beam = 2;
    const std::string error = error_of([&] { build_map(dir, unlike); });
    EXPECT_NE(error.find(flag), std::string::npos) << error;
    EXPECT_FALSE(fs::exists(dir / "work")) << "the refused build wrote its work directory";
  }
  fs::remove_all(dir);
}

// The quantizer of a build likewise: the existing codebook's whatever
// pq.quantizer says; an explicit --pq-quantizer unlike it is refused before
// the build writes anything, naming the flag and the map's quantizer.
TEST(MapBuildOptions, PqQuantizerFollowsTheExistingMapsCodebook) {
  const fs::path dir = unique_temp_dir("visloc_pq_quantizer");
  MapBuildOptions o;
  o.images_dir = dir;
  EXPECT_EQ(resolve_pq_quantizer(dir, o), PqQuantizer::kProduct);
  o.pq.quantizer = PqQuantizer::kResidual;
  EXPECT_EQ(resolve_pq_quantizer(dir, o), PqQuantizer::kResidual);
  o.pq_quantizer = PqQuantizer::kProduct;
  EXPECT_EQ(resolve_pq_quantizer(dir, o), PqQuantizer::kProduct);
  std::vector<float> product(kPqCentroidFloats), residual(size_t(16) * 256 * 64);
  for (size_t i = 0; i < product.size(); ++i) product[i] = float(i % 89);
  for (size_t i = 0; i < residual.size(); ++i) residual[i] = float(i % 97) - 40;
  for (const PqQuantizer existing : {PqQuantizer::kProduct, PqQuantizer::kResidual}) {
    (existing == PqQuantizer::kProduct ? PqCodebook(product) : PqCodebook::residual(residual, 2))
        .write(dir / "pq_codebook.vlpq", "{}");
    for (const PqQuantizer given : {PqQuantizer::kProduct, PqQuantizer::kResidual}) {
      MapBuildOptions resumed;
      resumed.images_dir = dir;
      resumed.pq.quantizer = given;
      EXPECT_EQ(resolve_pq_quantizer(dir, resumed), existing);
      resumed.pq_quantizer = given;
      if (given == existing) {
        EXPECT_EQ(resolve_pq_quantizer(dir, resumed), existing);
        continue;
      }
      try {
        build_map(dir, resumed);
        ADD_FAILURE() << "an explicit " << to_string(given) << " build of a " << to_string(existing) << " map";
      } catch (const Error& e) {
        EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument);
        EXPECT_NE(std::string(e.what()).find(std::string("--pq-quantizer ") + to_string(existing)), std::string::npos)
            << e.what();
      }
      EXPECT_FALSE(fs::exists(dir / "work")) << "the refused build wrote its work directory";
    }
  }
  fs::remove_all(dir);
}
