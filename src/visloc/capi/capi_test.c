/* The C API used from C (compiled as C99): error paths without data, then,
 * when the shared data is present, a held-out fountain-P11 photo localized
 * from its file against a map imported by the ctest fixture.
 *
 * Usage: visloc_capi_c_test SHARED_DATA_DIR MAP_DIR
 * Exit status: 0 pass, 1 fail, 77 skipped (data or map absent). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "visloc/capi/visloc.h"

static int failures = 0;

#define CHECK(cond, ...)                                                         \
  do {                                                                           \
    if (!(cond)) {                                                               \
      fprintf(stderr, "%s:%d: check failed: %s: ", __FILE__, __LINE__, #cond);   \
      fprintf(stderr, __VA_ARGS__);                                              \
      fputc('\n', stderr);                                                       \
      ++failures;                                                                \
    }                                                                            \
  } while (0)

/* dir/name into out; 0 when it does not fit. */
static int join(char* out, size_t size, const char* dir, const char* name) {
  const int n = snprintf(out, size, "%s/%s", dir, name);
  return n > 0 && (size_t)n < size;
}

static int file_exists(const char* path) {
  FILE* f = fopen(path, "rb");
  if (f == NULL) return 0;
  fclose(f);
  return 1;
}

static void test_strings_and_defaults(void) {
  const char* seen[8];
  int s, k;
  visloc_options o;
  CHECK(visloc_version() != NULL && visloc_version()[0] != '\0', "empty version");
  for (s = VISLOC_OK; s <= VISLOC_INTERNAL_ERROR; ++s) {
    seen[s] = visloc_status_string((visloc_status)s);
    CHECK(seen[s] != NULL && seen[s][0] != '\0', "status %d has no string", s);
    CHECK(strcmp(seen[s], "unknown status") != 0, "status %d is unknown", s);
    for (k = 0; k < s; ++k) CHECK(strcmp(seen[s], seen[k]) != 0, "statuses %d and %d share '%s'", k, s, seen[s]);
  }
  CHECK(strcmp(visloc_status_string((visloc_status)99), "unknown status") == 0, "99: %s",
        visloc_status_string((visloc_status)99));

  visloc_options_init(NULL); /* no effect, no crash */
  memset(&o, 0xff, sizeof(o));
  visloc_options_init(&o);
  CHECK(o.setting == VISLOC_SETTING_3_PLUS, "setting %d", (int)o.setting);
  CHECK(o.cache_bytes == 512ull << 20, "cache_bytes %llu", (unsigned long long)o.cache_bytes);
  CHECK(o.max_segments == 4 && o.top_images == 20, "max_segments %d top_images %d", o.max_segments, o.top_images);
  CHECK(o.max_image_side == 800 && o.max_features == 8192 && o.threads == 0, "sift %d %d %d", o.max_image_side,
        o.max_features, o.threads);
  CHECK(o.use_exif_focal == 1 && o.min_inliers == 12, "exif %d min_inliers %d", o.use_exif_focal, o.min_inliers);
  CHECK(o.min_confidence > 0 && o.min_confidence < 1, "min_confidence %f", o.min_confidence);
}

static void test_open_errors(void) {
  const char* missing = "/nonexistent/visloc_capi_test_map";
  visloc_localizer* loc = (visloc_localizer*)&failures; /* must be reset to NULL */
  char error[256];
  char small[8];
  visloc_status s;
  visloc_options o;

  s = visloc_localizer_open(missing, NULL, NULL, error, sizeof(error));
  CHECK(s == VISLOC_INVALID_ARGUMENT, "NULL out: %s", visloc_status_string(s));
  CHECK(strstr(error, "out") != NULL, "message '%s'", error);

  s = visloc_localizer_open(NULL, NULL, &loc, error, sizeof(error));
  CHECK(s == VISLOC_INVALID_ARGUMENT, "NULL map_dir: %s", visloc_status_string(s));
  CHECK(loc == NULL, "out not reset on failure");
  CHECK(strstr(error, "map_dir") != NULL, "message '%s'", error);

  loc = (visloc_localizer*)&failures;
  s = visloc_localizer_open(missing, NULL, &loc, error, sizeof(error));
  CHECK(s == VISLOC_IO_ERROR || s == VISLOC_NOT_FOUND, "missing map: %s", visloc_status_string(s));
  CHECK(loc == NULL, "out not reset on failure");
  CHECK(strstr(error, missing) != NULL, "message does not name the map: '%s'", error);

  /* A short buffer: truncated, NUL-terminated. No buffer at all: fine. */
  memset(small, 'x', sizeof(small));
  s = visloc_localizer_open(missing, NULL, &loc, small, sizeof(small));
  CHECK(s == VISLOC_IO_ERROR || s == VISLOC_NOT_FOUND, "missing map: %s", visloc_status_string(s));
  CHECK(strlen(small) == sizeof(small) - 1 && strncmp(small, error, sizeof(small) - 1) == 0, "truncated '%s'", small);
  s = visloc_localizer_open(missing, NULL, &loc, NULL, 0);
  CHECK(s == VISLOC_IO_ERROR || s == VISLOC_NOT_FOUND, "no buffer: %s", visloc_status_string(s));

  /* Bad options are reported before the map is read. */
  visloc_options_init(&o);
  o.max_segments = 0;
  s = visloc_localizer_open(missing, &o, &loc, error, sizeof(error));
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(error, "max_segments") != NULL, "%s: '%s'", visloc_status_string(s),
        error);
  visloc_options_init(&o);
  o.setting = (visloc_setting)9;
  s = visloc_localizer_open(missing, &o, &loc, error, sizeof(error));
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(error, "setting") != NULL, "%s: '%s'", visloc_status_string(s), error);
  visloc_options_init(&o);
  o.cache_bytes = 1000;
  s = visloc_localizer_open(missing, &o, &loc, error, sizeof(error));
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(error, "cache_bytes") != NULL, "%s: '%s'", visloc_status_string(s),
        error);
  visloc_options_init(&o);
  o.min_confidence = 1.5;
  s = visloc_localizer_open(missing, &o, &loc, error, sizeof(error));
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(error, "min_confidence") != NULL, "%s: '%s'",
        visloc_status_string(s), error);

  visloc_localizer_close(NULL);
}

static void test_localize_without_localizer(void) {
  visloc_result r;
  uint8_t pixels[16] = {0};
  visloc_status s;
  s = visloc_localize_file(NULL, "x.jpg", NULL, &r);
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(r.error, "localizer") != NULL, "%s: '%s'", visloc_status_string(s),
        r.error);
  CHECK(r.registered == 0 && r.segment == -1, "result not cleared");
  s = visloc_localize_gray(NULL, pixels, 4, 4, 4, NULL, &r);
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(r.error, "localizer") != NULL, "%s: '%s'", visloc_status_string(s),
        r.error);
  CHECK(visloc_localize_file(NULL, "x.jpg", NULL, NULL) == VISLOC_INVALID_ARGUMENT, "NULL result");
  CHECK(visloc_localize_gray(NULL, pixels, 4, 4, 4, NULL, NULL) == VISLOC_INVALID_ARGUMENT, "NULL result");
}

/* PINHOLE fx fy cx cy of the single camera in COLMAP's cameras.txt. */
static int read_pinhole(const char* path, visloc_intrinsics* k) {
  char line[512], model[64];
  int id, w, h;
  FILE* f = fopen(path, "r");
  if (f == NULL) return 0;
  memset(k, 0, sizeof(*k));
  while (fgets(line, sizeof(line), f) != NULL) {
    if (line[0] == '#') continue;
    if (sscanf(line, "%d %63s %d %d %lf %lf %lf %lf", &id, model, &w, &h, &k->fx, &k->fy, &k->cx, &k->cy) == 8 &&
        strcmp(model, "PINHOLE") == 0) {
      fclose(f);
      return 1;
    }
  }
  fclose(f);
  return 0;
}

/* The camera centre -R^T t of the pose (q wxyz, t): X_cam = R X_world + t. */
static void center_of(const double q[4], const double t[3], double c[3]) {
  const double w = q[0], x = q[1], y = q[2], z = q[3];
  const double R[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                          {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                          {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
  int i;
  for (i = 0; i < 3; ++i) c[i] = -(R[0][i] * t[0] + R[1][i] * t[1] + R[2][i] * t[2]);
}

/* The quaternion and camera centre of `name` in a truth.txt pose list. */
static int read_truth(const char* path, const char* name, double q[4], double center[3]) {
  char line[512], n[128];
  double t[3];
  FILE* f = fopen(path, "r");
  if (f == NULL) return 0;
  while (fgets(line, sizeof(line), f) != NULL) {
    if (sscanf(line, "%127s %lf %lf %lf %lf %lf %lf %lf", n, &q[0], &q[1], &q[2], &q[3], &t[0], &t[1], &t[2]) != 8 ||
        strcmp(n, name) != 0)
      continue;
    center_of(q, t, center);
    fclose(f);
    return 1;
  }
  fclose(f);
  return 0;
}

static double distance3(const double a[3], const double b[3]) {
  return sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
}

/* Angle between two rotations given as unit quaternions, degrees. */
static double rotation_angle_deg(const double a[4], const double b[4]) {
  double d = fabs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]);
  if (d > 1) d = 1;
  return 2 * acos(d) * 180.0 / 3.14159265358979323846;
}

static void test_fountain(const char* scene, const char* map_dir) {
  char path[4096], image[4096], error[256];
  visloc_options o;
  visloc_localizer* loc = NULL;
  visloc_intrinsics k, bad;
  visloc_result r;
  visloc_status s;
  double q_truth[4], c_truth[3], c[3];
  uint8_t* blank;

  CHECK(join(path, sizeof(path), scene, "colmap/sparse/cameras.txt"), "path too long");
  CHECK(read_pinhole(path, &k), "no PINHOLE camera in %s", path);
  CHECK(join(path, sizeof(path), scene, "truth.txt"), "path too long");
  CHECK(read_truth(path, "0006.jpg", q_truth, c_truth), "0006.jpg not in %s", path);
  if (failures) return;

  visloc_options_init(&o);
  o.max_features = 16384; /* as the demo */
  s = visloc_localizer_open(map_dir, &o, &loc, error, sizeof(error));
  CHECK(s == VISLOC_OK && loc != NULL, "open %s: %s: %s", map_dir, visloc_status_string(s), error);
  CHECK(error[0] == '\0', "message on success: '%s'", error);
  if (s != VISLOC_OK) return;

  /* A missing image and a file that is not an image. */
  CHECK(join(path, sizeof(path), scene, "images/missing.jpg"), "path too long");
  s = visloc_localize_file(loc, path, &k, &r);
  CHECK(s == VISLOC_IO_ERROR && strstr(r.error, "missing.jpg") != NULL, "%s: '%s'", visloc_status_string(s), r.error);
  CHECK(r.registered == 0 && r.segment == -1, "result of a failed call not cleared");
  CHECK(join(path, sizeof(path), scene, "queries.txt"), "path too long");
  s = visloc_localize_file(loc, path, &k, &r);
  CHECK(s == VISLOC_FORMAT_ERROR && strstr(r.error, "queries.txt") != NULL, "%s: '%s'", visloc_status_string(s),
        r.error);

  /* Bad intrinsics. */
  CHECK(join(image, sizeof(image), scene, "images/0006.jpg"), "path too long");
  bad = k;
  bad.fx = -1;
  s = visloc_localize_file(loc, image, &bad, &r);
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(r.error, "fx") != NULL, "%s: '%s'", visloc_status_string(s), r.error);
  bad = k;
  bad.fy = 3 * k.fx;
  s = visloc_localize_file(loc, image, &bad, &r);
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(r.error, "aspect") != NULL, "%s: '%s'", visloc_status_string(s),
        r.error);

  /* Bad pixel buffers, and a blank frame: processed, not placed, no error. */
  blank = (uint8_t*)calloc(64 * 48, 1);
  s = visloc_localize_gray(loc, NULL, 64, 48, 64, NULL, &r);
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(r.error, "pixels") != NULL, "%s: '%s'", visloc_status_string(s),
        r.error);
  s = visloc_localize_gray(loc, blank, 64, 48, 63, NULL, &r);
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(r.error, "stride") != NULL, "%s: '%s'", visloc_status_string(s),
        r.error);
  s = visloc_localize_gray(loc, blank, 0, 48, 64, NULL, &r);
  CHECK(s == VISLOC_INVALID_ARGUMENT && strstr(r.error, "width") != NULL, "%s: '%s'", visloc_status_string(s),
        r.error);
  s = visloc_localize_gray(loc, blank, 64, 48, 64, NULL, &r);
  CHECK(s == VISLOC_OK && r.error[0] == '\0', "blank frame: %s: '%s'", visloc_status_string(s), r.error);
  CHECK(r.registered == 0 && r.segment == -1 && r.features == 0, "blank frame: registered %d segment %d features %d",
        r.registered, r.segment, r.features);
  free(blank);

  /* A held-out photo with the ground-truth intrinsics. */
  s = visloc_localize_file(loc, image, &k, &r);
  CHECK(s == VISLOC_OK && r.error[0] == '\0', "%s: %s: '%s'", image, visloc_status_string(s), r.error);
  CHECK(r.registered == 1 && r.segment == 0 && r.inliers >= o.min_inliers, "registered %d segment %d inliers %d",
        r.registered, r.segment, r.inliers);
  CHECK(distance3(r.center, c_truth) < 0.25, "centre (%.3f %.3f %.3f), truth (%.3f %.3f %.3f): %.3f m", r.center[0],
        r.center[1], r.center[2], c_truth[0], c_truth[1], c_truth[2], distance3(r.center, c_truth));
  CHECK(rotation_angle_deg(r.rotation_wxyz, q_truth) < 1.0, "rotation error %.3f deg",
        rotation_angle_deg(r.rotation_wxyz, q_truth));
  center_of(r.rotation_wxyz, r.translation, c);
  CHECK(distance3(c, r.center) < 1e-9, "centre is not -R^T t of the pose");
  CHECK(fabs(r.focal_px - k.fx) < 1e-9 && r.focal_estimated == 0, "focal %.3f estimated %d", r.focal_px,
        r.focal_estimated);
  CHECK(r.has_enu == 0 && r.has_geo == 0 && r.has_heading == 0, "an imported COLMAP model is not geo-registered");
  CHECK(r.confidence >= o.min_confidence && r.confidence <= 1, "confidence %f (threshold %f)", r.confidence,
        o.min_confidence);
  CHECK(r.has_sigma == 1 && r.position_sigma > 0 && r.position_sigma < 0.25 && r.rotation_sigma_deg > 0,
        "sigma %d position %f rotation %f", r.has_sigma, r.position_sigma, r.rotation_sigma_deg);
  CHECK(r.position_sigma_m == 0 && r.has_heading_sigma == 0, "metric sigmas need a geo-registered map");
  CHECK(r.features > 1000 && r.features <= o.max_features, "features %d", r.features);
  CHECK(r.times.total_ms > 0 && r.times.total_ms >= r.times.features_ms && r.times.features_ms > 0,
        "times total %.1f features %.1f", r.times.total_ms, r.times.features_ms);
  printf("%s: registered, %d inliers, centre error %.3f m, rotation error %.3f deg, %.0f ms\n", image, r.inliers,
         distance3(r.center, c_truth), rotation_angle_deg(r.rotation_wxyz, q_truth), r.times.total_ms);

  visloc_localizer_close(loc);
}

int main(int argc, char** argv) {
  char probe[4096];
  test_strings_and_defaults();
  test_open_errors();
  test_localize_without_localizer();
  if (argc < 3) {
    fprintf(stderr, "usage: %s SHARED_DATA_DIR MAP_DIR\n", argv[0]);
    return 1;
  }
  {
    char scene[4096];
    CHECK(join(scene, sizeof(scene), argv[1], "strecha/fountain-P11"), "path too long");
    CHECK(join(probe, sizeof(probe), scene, "images/0006.jpg"), "path too long");
    if (!file_exists(probe)) {
      printf("skipped the fountain-P11 run: shared data absent (%s)\n", probe);
      return failures ? 1 : 77;
    }
    CHECK(join(probe, sizeof(probe), argv[2], "manifest.json"), "path too long");
    if (!file_exists(probe)) {
      printf("skipped the fountain-P11 run: no map at %s (the ctest fixture imports it)\n", argv[2]);
      return failures ? 1 : 77;
    }
    test_fountain(scene, argv[2]);
  }
  if (failures) fprintf(stderr, "%d checks failed\n", failures);
  return failures ? 1 : 0;
}
