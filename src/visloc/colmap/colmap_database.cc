#include "visloc/colmap/colmap_database.h"

#include <sqlite3.h>

#include <cmath>
#include <cstring>

#include "visloc/util/error.h"

namespace visloc {
namespace {

// RAII prepared statement.
class Statement {
 public:
  Statement(sqlite3* db, const std::filesystem::path& path, const char* sql) : path_(path) {
    if (sqlite3_prepare_v2(db, sql, -1, &stmt_, nullptr) != SQLITE_OK)
      throw_error(ErrorCode::kFormat, path.string(), ": not a COLMAP database (", sqlite3_errmsg(db),
                  " in '", sql, "')");
  }
  ~Statement() { sqlite3_finalize(stmt_); }
  void bind(int i, int64_t v) { sqlite3_bind_int64(stmt_, i, v); }
  void bind(int i, const std::string& s) { sqlite3_bind_text(stmt_, i, s.c_str(), -1, SQLITE_TRANSIENT); }
  bool step() {
    int rc = sqlite3_step(stmt_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    throw_error(ErrorCode::kIo, path_.string(), ": SQLite error ", rc);
  }
  int64_t integer(int col) const { return sqlite3_column_int64(stmt_, col); }
  std::string text(int col) const {
    const auto* p = sqlite3_column_text(stmt_, col);
    return p ? reinterpret_cast<const char*>(p) : "";
  }
  std::pair<const void*, size_t> blob(int col) const {
    return {sqlite3_column_blob(stmt_, col), static_cast<size_t>(sqlite3_column_bytes(stmt_, col))};
  }

 private:
  std::filesystem::path path_;
  sqlite3_stmt* stmt_ = nullptr;
};

}  // namespace

int64_t colmap_pair_id(int64_t a, int64_t b) {
  // COLMAP's image ids are in [1, 2^31 - 1]; others cannot form a pair id
  // (their product overflowed: found by fuzzing).
  if (a < 1 || b < 1 || a > 2147483647 || b > 2147483647)
    throw_error(ErrorCode::kFormat, "COLMAP image ids ", a, " and ", b, " are outside [1, 2^31 - 1]");
  if (a > b) std::swap(a, b);
  return a * 2147483647 + b;
}

ColmapDatabase::ColmapDatabase(const std::filesystem::path& path) : path_(path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))
    throw_error(ErrorCode::kIo, path.string(), ": no such COLMAP database");
  if (sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READONLY, nullptr) != SQLITE_OK) {
    std::string msg = db_ ? sqlite3_errmsg(db_) : "out of memory";
    sqlite3_close(db_);
    db_ = nullptr;
    throw_error(ErrorCode::kIo, path.string(), ": cannot open database: ", msg);
  }
  // Validate the schema now so that later calls fail only on real I/O errors.
  // The destructor does not run when the constructor throws: close here.
  try {
    Statement(db_, path_, "SELECT image_id, name, camera_id FROM images LIMIT 1");
    Statement(db_, path_, "SELECT image_id, rows, cols, data FROM keypoints LIMIT 1");
    Statement(db_, path_, "SELECT image_id, rows, cols, data FROM descriptors LIMIT 1");
  } catch (...) {
    sqlite3_close(db_);
    db_ = nullptr;
    throw;
  }
}

ColmapDatabase::~ColmapDatabase() { sqlite3_close(db_); }

std::vector<ColmapDbCamera> ColmapDatabase::cameras() const {
  Statement s(db_, path_, "SELECT camera_id, model, width, height, params, prior_focal_length FROM cameras");
  std::vector<ColmapDbCamera> out;
  while (s.step()) {
    ColmapDbCamera c;
    c.camera_id = s.integer(0);
    c.model = static_cast<int>(s.integer(1));
    c.width = s.integer(2);
    c.height = s.integer(3);
    auto [p, n] = s.blob(4);
    if (n % sizeof(double) != 0)
      throw_error(ErrorCode::kFormat, path_.string(), ": camera ", c.camera_id, " has a params blob of ", n,
                  " bytes, not a whole number of doubles");
    c.params.resize(n / sizeof(double));
    if (!c.params.empty()) std::memcpy(c.params.data(), p, n);  // (found by fuzzing: 1-7 bytes copied to null)
    c.prior_focal_length = s.integer(5) != 0;
    out.push_back(std::move(c));
  }
  return out;
}

std::vector<ColmapDbImage> ColmapDatabase::images() const {
  Statement s(db_, path_, "SELECT image_id, name, camera_id FROM images ORDER BY image_id");
  std::vector<ColmapDbImage> out;
  while (s.step()) out.push_back({s.integer(0), s.text(1), s.integer(2)});
  return out;
}

std::optional<ColmapDbImage> ColmapDatabase::image_by_name(const std::string& name) const {
  Statement s(db_, path_, "SELECT image_id, name, camera_id FROM images WHERE name = ?");
  s.bind(1, name);
  if (!s.step()) return std::nullopt;
  return ColmapDbImage{s.integer(0), s.text(1), s.integer(2)};
}

std::vector<Keypoint> ColmapDatabase::keypoints(int64_t image_id) const {
  Statement s(db_, path_, "SELECT rows, cols, data FROM keypoints WHERE image_id = ?");
  s.bind(1, image_id);
  if (!s.step()) return {};
  const int64_t rows = s.integer(0), cols = s.integer(1);
  auto [p, n] = s.blob(2);
  // rows is bounded by the blob first, so that no product below overflows.
  if (rows < 0 || static_cast<uint64_t>(rows) > n || (cols != 2 && cols != 4 && cols != 6) ||
      n != static_cast<uint64_t>(rows) * static_cast<uint64_t>(cols) * sizeof(float))
    throw_error(ErrorCode::kFormat, path_.string(), ": keypoints of image ", image_id, " have ",
                rows, "x", cols, " values in ", n, " bytes");
  std::vector<float> v(rows * cols);
  if (n) std::memcpy(v.data(), p, n);
  std::vector<Keypoint> out(rows);
  for (int64_t i = 0; i < rows; ++i) {
    const float* r = &v[i * cols];
    Keypoint& k = out[i];
    k.x = r[0];
    k.y = r[1];
    if (cols == 4) {
      k.scale = r[2];
      k.orientation = r[3];
    } else if (cols == 6) {  // affine shape [a11 a12; a21 a22]
      k.scale = std::sqrt(r[2] * r[2] + r[4] * r[4]);
      k.orientation = std::atan2(r[4], r[2]);
    } else {
      k.scale = 1;
    }
  }
  return out;
}

DescriptorMatrix ColmapDatabase::descriptors(int64_t image_id) const {
  Statement s(db_, path_, "SELECT rows, cols, data FROM descriptors WHERE image_id = ?");
  s.bind(1, image_id);
  if (!s.step()) return {};
  const int64_t rows = s.integer(0), cols = s.integer(1);
  auto [p, n] = s.blob(2);
  if (rows < 0 || static_cast<uint64_t>(rows) > n || cols != kDescriptorDim ||
      n != static_cast<uint64_t>(rows) * kDescriptorDim)
    throw_error(ErrorCode::kFormat, path_.string(), ": descriptors of image ", image_id, " have ",
                rows, "x", cols, " values in ", n, " bytes (expected uint8 × 128)");
  return DescriptorMatrix(static_cast<const uint8_t*>(p), rows);
}

FeatureSet ColmapDatabase::features(int64_t image_id) const {
  FeatureSet f;
  f.keypoints = keypoints(image_id);
  f.descriptors = descriptors(image_id);
  if (f.keypoints.size() != f.descriptors.rows())
    throw_error(ErrorCode::kFormat, path_.string(), ": image ", image_id, " has ", f.keypoints.size(),
                " keypoints but ", f.descriptors.rows(), " descriptors");
  Statement s(db_, path_,
              "SELECT images.name, cameras.width, cameras.height FROM images JOIN cameras ON "
              "images.camera_id = cameras.camera_id WHERE images.image_id = ?");
  s.bind(1, image_id);
  if (s.step()) {
    f.image = s.text(0);
    f.image_width = static_cast<int>(s.integer(1));
    f.image_height = static_cast<int>(s.integer(2));
  }
  f.extractor = R"({"type":"colmap-database"})";
  return f;
}

std::vector<std::pair<uint32_t, uint32_t>> ColmapDatabase::verified_matches(int64_t id1, int64_t id2) const {
  Statement s(db_, path_, "SELECT rows, cols, data FROM two_view_geometries WHERE pair_id = ?");
  s.bind(1, colmap_pair_id(id1, id2));
  if (!s.step()) return {};
  const int64_t rows = s.integer(0), cols = s.integer(1);
  auto [p, n] = s.blob(2);
  if (rows == 0 || n == 0) return {};
  if (rows < 0 || static_cast<uint64_t>(rows) > n || cols != 2 || n != static_cast<uint64_t>(rows) * 2 * sizeof(uint32_t))
    throw_error(ErrorCode::kFormat, path_.string(), ": two-view geometry of images ", id1, ", ", id2,
                " has a bad match blob");
  std::vector<std::pair<uint32_t, uint32_t>> out(rows);
  const auto* m = static_cast<const uint32_t*>(p);
  const bool swapped = id1 > id2;
  for (int64_t i = 0; i < rows; ++i)
    out[i] = swapped ? std::make_pair(m[2 * i + 1], m[2 * i]) : std::make_pair(m[2 * i], m[2 * i + 1]);
  return out;
}

}  // namespace visloc
