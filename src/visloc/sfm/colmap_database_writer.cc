#include "visloc/sfm/colmap_database_writer.h"

#include <sqlite3.h>

#include <iomanip>
#include <sstream>

#include "visloc/colmap/colmap_model.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {
namespace {

constexpr const char* kSchema = R"SQL(
CREATE TABLE IF NOT EXISTS cameras (camera_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL,
  model INTEGER NOT NULL, width INTEGER NOT NULL, height INTEGER NOT NULL, params BLOB,
  prior_focal_length INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS images (image_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL,
  name TEXT NOT NULL UNIQUE, camera_id INTEGER NOT NULL,
  prior_qw REAL, prior_qx REAL, prior_qy REAL, prior_qz REAL, prior_tx REAL, prior_ty REAL, prior_tz REAL,
  CONSTRAINT image_id_check CHECK(image_id >= 0 and image_id < 2147483647),
  FOREIGN KEY(camera_id) REFERENCES cameras(camera_id));
CREATE UNIQUE INDEX IF NOT EXISTS index_name ON images(name);
CREATE TABLE IF NOT EXISTS keypoints (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
  cols INTEGER NOT NULL, data BLOB, FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS descriptors (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
  cols INTEGER NOT NULL, data BLOB, FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS matches (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
  cols INTEGER NOT NULL, data BLOB);
CREATE TABLE IF NOT EXISTS two_view_geometries (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
  cols INTEGER NOT NULL, data BLOB, config INTEGER NOT NULL, F BLOB, E BLOB, H BLOB, qvec BLOB, tvec BLOB);
)SQL";

class Stmt {
 public:
  Stmt(sqlite3* db, const std::filesystem::path& path, const char* sql) : db_(db), path_(path) {
    if (sqlite3_prepare_v2(db, sql, -1, &s_, nullptr) != SQLITE_OK)
      throw_error(ErrorCode::kIo, path.string(), ": SQLite: ", sqlite3_errmsg(db));
  }
  ~Stmt() { sqlite3_finalize(s_); }
  sqlite3_stmt* get() { return s_; }
  void run() {
    if (sqlite3_step(s_) != SQLITE_DONE)
      throw_error(ErrorCode::kIo, path_.string(), ": SQLite: ", sqlite3_errmsg(db_));
  }

 private:
  sqlite3* db_;
  std::filesystem::path path_;
  sqlite3_stmt* s_ = nullptr;
};

void exec(sqlite3* db, const std::filesystem::path& path, const char* sql) {
  char* err = nullptr;
  if (sqlite3_exec(db, sql, nullptr, nullptr, &err) != SQLITE_OK) {
    std::string msg = err ? err : "unknown";
    sqlite3_free(err);
    throw_error(ErrorCode::kIo, path.string(), ": SQLite: ", msg);
  }
}

}  // namespace

ColmapDatabaseWriter::ColmapDatabaseWriter(const std::filesystem::path& path, Mode mode) : path_(path) {
  std::error_code ec;
  if (mode == Mode::kCreate) std::filesystem::remove(path, ec);
  else if (!std::filesystem::is_regular_file(path))
    throw_error(ErrorCode::kNotFound, path.string(), ": no such COLMAP database");
  const int flags = SQLITE_OPEN_READWRITE | (mode == Mode::kCreate ? SQLITE_OPEN_CREATE : 0);
  if (sqlite3_open_v2(path.c_str(), &db_, flags, nullptr) != SQLITE_OK) {
    std::string msg = db_ ? sqlite3_errmsg(db_) : "out of memory";
    sqlite3_close(db_);
    db_ = nullptr;
    throw_error(ErrorCode::kIo, path.string(), ": cannot create database: ", msg);
  }
  exec(db_, path_, kSchema);
  exec(db_, path_, "BEGIN TRANSACTION");
}

ColmapDatabaseWriter::~ColmapDatabaseWriter() {
  if (db_ && !committed_) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
  sqlite3_close(db_);
}

int64_t ColmapDatabaseWriter::add_camera(const PinholeCamera& c, double fallback_focal) {
  const double f = c.has_focal ? c.focal : fallback_focal;
  if (!(f > 0)) throw_error(ErrorCode::kInvalidArgument, "COLMAP camera needs a focal length (known or fallback)");
  PinholeCamera known = c;
  known.focal = f;
  const auto [model_name, params] = known.colmap_model();
  const int model = colmap_camera_model_id(model_name);
  Stmt s(db_, path_, "INSERT INTO cameras(model, width, height, params, prior_focal_length) VALUES(?,?,?,?,?)");
  sqlite3_bind_int(s.get(), 1, model);
  sqlite3_bind_int64(s.get(), 2, c.width);
  sqlite3_bind_int64(s.get(), 3, c.height);
  sqlite3_bind_blob(s.get(), 4, params.data(), static_cast<int>(params.size() * sizeof(double)), SQLITE_TRANSIENT);
  sqlite3_bind_int(s.get(), 5, c.has_focal ? 1 : 0);
  s.run();
  return sqlite3_last_insert_rowid(db_);
}

int64_t ColmapDatabaseWriter::add_image(const std::string& name, int64_t camera_id,
                                        const std::optional<Eigen::Vector3d>& prior) {
  Stmt s(db_, path_, "INSERT INTO images(name, camera_id, prior_tx, prior_ty, prior_tz) VALUES(?,?,?,?,?)");
  sqlite3_bind_text(s.get(), 1, name.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_int64(s.get(), 2, camera_id);
  for (int i = 0; i < 3; ++i) {
    if (prior) sqlite3_bind_double(s.get(), 3 + i, (*prior)[i]);
    else sqlite3_bind_null(s.get(), 3 + i);
  }
  s.run();
  return sqlite3_last_insert_rowid(db_);
}

void ColmapDatabaseWriter::add_features(int64_t image_id, const FeatureSet& f) {
  f.check_consistent();
  std::vector<float> kp(f.size() * 4);
  for (size_t i = 0; i < f.size(); ++i) {
    kp[4 * i] = f.keypoints[i].x;
    kp[4 * i + 1] = f.keypoints[i].y;
    kp[4 * i + 2] = f.keypoints[i].scale;
    kp[4 * i + 3] = f.keypoints[i].orientation;
  }
  {
    Stmt s(db_, path_, "INSERT INTO keypoints(image_id, rows, cols, data) VALUES(?,?,4,?)");
    sqlite3_bind_int64(s.get(), 1, image_id);
    sqlite3_bind_int64(s.get(), 2, static_cast<int64_t>(f.size()));
    sqlite3_bind_blob(s.get(), 3, kp.data(), static_cast<int>(kp.size() * sizeof(float)), SQLITE_TRANSIENT);
    s.run();
  }
  Stmt s(db_, path_, "INSERT INTO descriptors(image_id, rows, cols, data) VALUES(?,?,128,?)");
  sqlite3_bind_int64(s.get(), 1, image_id);
  sqlite3_bind_int64(s.get(), 2, static_cast<int64_t>(f.size()));
  sqlite3_bind_blob(s.get(), 3, f.descriptors.data(), static_cast<int>(f.descriptors.size_bytes()), SQLITE_TRANSIENT);
  s.run();
}

void ColmapDatabaseWriter::add_calibrated_pair(int64_t id1, int64_t id2,
                                               const std::vector<std::pair<uint32_t, uint32_t>>& matches,
                                               const Eigen::Matrix3d& F, const Eigen::Matrix3d& E,
                                               const Eigen::Quaterniond& rotation, const Eigen::Vector3d& direction) {
  add_pair(id1, id2, matches, matches, kColmapCalibratedPair, F, E, rotation, direction);
}

void ColmapDatabaseWriter::add_verified_pair(int64_t id1, int64_t id2,
                                             const std::vector<std::pair<uint32_t, uint32_t>>& matches,
                                             const std::vector<std::pair<uint32_t, uint32_t>>& inliers,
                                             const Eigen::Matrix3d& F, const std::optional<Eigen::Matrix3d>& E) {
  add_pair(id1, id2, matches, inliers, E ? kColmapCalibratedPair : kColmapUncalibratedPair, F,
           E.value_or(Eigen::Matrix3d::Zero()), Eigen::Quaterniond::Identity(), Eigen::Vector3d::Zero());
}

namespace {

// Index pairs as COLMAP's N × 2 uint32 blob, columns swapped when the pair
// is stored the other way round.
std::vector<uint32_t> match_blob(const std::vector<std::pair<uint32_t, uint32_t>>& matches, bool swap) {
  std::vector<uint32_t> data(matches.size() * 2);
  for (size_t i = 0; i < matches.size(); ++i) {
    data[2 * i] = swap ? matches[i].second : matches[i].first;
    data[2 * i + 1] = swap ? matches[i].first : matches[i].second;
  }
  return data;
}

}  // namespace

void ColmapDatabaseWriter::add_pair(int64_t id1, int64_t id2, const std::vector<std::pair<uint32_t, uint32_t>>& matches,
                                    const std::vector<std::pair<uint32_t, uint32_t>>& inliers, int config,
                                    const Eigen::Matrix3d& F_in, const Eigen::Matrix3d& E_in,
                                    const Eigen::Quaterniond& rotation_in, const Eigen::Vector3d& direction_in) {
  if (id1 == id2) throw_error(ErrorCode::kInvalidArgument, "COLMAP pair of image ", id1, " with itself");
  Eigen::Matrix3d F = F_in, E = E_in;
  Eigen::Quaterniond q = rotation_in;
  Eigen::Vector3d t = direction_in;
  const bool swap = id1 > id2;
  if (swap) {
    std::swap(id1, id2);
    F.transposeInPlace();
    E.transposeInPlace();
    q = q.conjugate();
    t = -(q * t);
  }
  const std::vector<uint32_t> raw = match_blob(matches, swap), fitting = match_blob(inliers, swap);
  constexpr int64_t kMax = 2147483647;
  const int64_t pair_id = id1 * kMax + id2;
  {
    Stmt s(db_, path_, "INSERT OR REPLACE INTO matches(pair_id, rows, cols, data) VALUES(?,?,2,?)");
    sqlite3_bind_int64(s.get(), 1, pair_id);
    sqlite3_bind_int64(s.get(), 2, static_cast<int64_t>(matches.size()));
    sqlite3_bind_blob(s.get(), 3, raw.data(), static_cast<int>(raw.size() * sizeof(uint32_t)), SQLITE_TRANSIENT);
    s.run();
  }
  // Row-major 3x3 blobs.
  double f[9], e[9], h[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      f[3 * r + c] = F(r, c);
      e[3 * r + c] = E(r, c);
    }
  const double qvec[4] = {q.w(), q.x(), q.y(), q.z()};
  const double tvec[3] = {t.x(), t.y(), t.z()};
  Stmt s(db_, path_,
         "INSERT OR REPLACE INTO two_view_geometries(pair_id, rows, cols, data, config, F, E, H, qvec, tvec) "
         "VALUES(?,?,2,?,?,?,?,?,?,?)");
  sqlite3_bind_int64(s.get(), 1, pair_id);
  sqlite3_bind_int64(s.get(), 2, static_cast<int64_t>(inliers.size()));
  sqlite3_bind_blob(s.get(), 3, fitting.data(), static_cast<int>(fitting.size() * sizeof(uint32_t)), SQLITE_TRANSIENT);
  sqlite3_bind_int(s.get(), 4, config);
  sqlite3_bind_blob(s.get(), 5, f, sizeof f, SQLITE_TRANSIENT);
  sqlite3_bind_blob(s.get(), 6, e, sizeof e, SQLITE_TRANSIENT);
  sqlite3_bind_blob(s.get(), 7, h, sizeof h, SQLITE_TRANSIENT);
  sqlite3_bind_blob(s.get(), 8, qvec, sizeof qvec, SQLITE_TRANSIENT);
  sqlite3_bind_blob(s.get(), 9, tvec, sizeof tvec, SQLITE_TRANSIENT);
  s.run();
}

bool ColmapDatabaseWriter::remove_image(const std::string& name) {
  int64_t id = -1;
  {
    Stmt s(db_, path_, "SELECT image_id FROM images WHERE name = ?");
    sqlite3_bind_text(s.get(), 1, name.c_str(), -1, SQLITE_TRANSIENT);
    if (sqlite3_step(s.get()) == SQLITE_ROW) id = sqlite3_column_int64(s.get(), 0);
  }
  if (id < 0) return false;
  // Pair ids: id1 * 2147483647 + id2 with id1 < id2 (COLMAP).
  constexpr int64_t kMax = 2147483647;
  for (const char* table : {"matches", "two_view_geometries"}) {
    const std::string sql = std::string("DELETE FROM ") + table + " WHERE pair_id / " + std::to_string(kMax) +
                            " = ?1 OR pair_id % " + std::to_string(kMax) + " = ?1";
    Stmt s(db_, path_, sql.c_str());
    sqlite3_bind_int64(s.get(), 1, id);
    s.run();
  }
  for (const char* table : {"keypoints", "descriptors", "images"}) {
    const std::string sql = std::string("DELETE FROM ") + table + " WHERE image_id = ?";
    Stmt s(db_, path_, sql.c_str());
    sqlite3_bind_int64(s.get(), 1, id);
    s.run();
  }
  return true;
}

void ColmapDatabaseWriter::commit() {
  exec(db_, path_, "COMMIT");
  committed_ = true;
}

void write_colmap_text_model(const std::filesystem::path& dir, const std::vector<ColmapTextCamera>& cameras,
                             const std::vector<ColmapTextImage>& images) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw_error(ErrorCode::kIo, "cannot create ", dir.string(), ": ", ec.message());
  std::ostringstream c;
  c << std::setprecision(17) << "# Camera list: CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n";
  for (const auto& cam : cameras) {
    const auto& k = cam.camera;
    if (!k.has_focal) throw_error(ErrorCode::kInvalidArgument, "text model camera ", cam.camera_id, " has no focal length");
    const auto [model_name, params] = k.colmap_model();
    c << cam.camera_id << ' ' << model_name << ' ' << k.width << ' ' << k.height;
    for (double v : params) c << ' ' << v;
    c << '\n';
  }
  std::ostringstream im;
  im << std::setprecision(17) << "# Image list: IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME; then POINTS2D\n";
  for (const auto& img : images) {
    const auto q = img.cam_from_world.q_wxyz();
    const auto& t = img.cam_from_world.translation;
    im << img.image_id << ' ' << q[0] << ' ' << q[1] << ' ' << q[2] << ' ' << q[3] << ' ' << t.x() << ' ' << t.y()
       << ' ' << t.z() << ' ' << img.camera_id << ' ' << img.name << "\n\n";
  }
  write_file_atomic(dir / "cameras.txt", c.str());
  write_file_atomic(dir / "images.txt", im.str());
  write_file_atomic(dir / "points3D.txt", "# 3D point list (empty: to be triangulated)\n");
}

}  // namespace visloc
