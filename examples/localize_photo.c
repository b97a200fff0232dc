/* localize_photo: the C API from an app's side (docs/embedding.md,
 * docs/device.md). Opens a map, localizes photos, prints one JSON line per
 * photo (pose, inliers, stage times, peak memory so far), so that runs on
 * two machines (x86-64, aarch64 under qemu) can be compared line by line.
 *
 *   localize_photo MAP_DIR [options] PHOTO...
 *     --intrinsics FILE   hloc query list: NAME MODEL WIDTH HEIGHT PARAMS...
 *                         (SIMPLE_PINHOLE f cx cy, PINHOLE fx fy cx cy,
 *                         SIMPLE_RADIAL f cx cy k); photos not listed use EXIF
 *                         or an estimated focal length
 *     --max-side N        downscale larger photos before SIFT (default 800)
 *     --max-features N    strongest SIFT features kept (default 8192)
 *     --cache-mib N       segments kept in memory (default 512)
 *     --max-segments N    candidate segments per photo (default 4)
 *     --threads N         OpenCV threads (default: OpenCV's)
 *     --open-only         open the map, report, and stop
 *
 * Exit status: 0 when every call returned VISLOC_OK (registered or not),
 * 1 on a failed call, 2 on bad arguments. Linked against libvisloc.so only. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>

#include "visloc/capi/visloc.h"

/* Peak resident memory of this process so far, KiB (under qemu-user: of the
 * emulator, i.e. the guest's pages plus qemu's own). */
static long peak_rss_kib(void) {
  struct rusage usage;
  if (getrusage(RUSAGE_SELF, &usage) != 0) return -1;
  return usage.ru_maxrss;
}

static int parse_int(const char* text, int lo, int hi, int* out) {
  char* end = NULL;
  long v = strtol(text, &end, 10);
  if (end == text || *end != '\0' || v < lo || v > hi) return 0;
  *out = (int)v;
  return 1;
}

static const char* base_name(const char* path) {
  const char* slash = strrchr(path, '/');
  return slash ? slash + 1 : path;
}

/* Looks up `name` in an hloc intrinsics list. Returns 1 and fills `k` when
 * found, 0 when not listed, -1 on a malformed line (message on stderr). */
static int find_intrinsics(const char* list_path, const char* name, visloc_intrinsics* k) {
  FILE* f = fopen(list_path, "r");
  char line[1024];
  int line_no = 0, found = 0;
  if (!f) {
    fprintf(stderr, "localize_photo: cannot open the intrinsics list %s\n", list_path);
    return -1;
  }
  while (!found && fgets(line, sizeof line, f)) {
    char entry[512], model[64];
    int width, height, n;
    double p[4] = {0, 0, 0, 0};
    ++line_no;
    if (line[0] == '#' || line[0] == '\n') continue;
    n = sscanf(line, "%511s %63s %d %d %lf %lf %lf %lf", entry, model, &width, &height, &p[0], &p[1], &p[2], &p[3]);
    if (n < 4) {
      fprintf(stderr, "localize_photo: %s line %d: expected NAME MODEL WIDTH HEIGHT PARAMS\n", list_path, line_no);
      fclose(f);
      return -1;
    }
    if (strcmp(entry, name) != 0) continue;
    memset(k, 0, sizeof *k);
    if (strcmp(model, "PINHOLE") == 0 && n == 8) {
      k->fx = p[0], k->fy = p[1], k->cx = p[2], k->cy = p[3];
    } else if (strcmp(model, "SIMPLE_PINHOLE") == 0 && n == 7) {
      k->fx = k->fy = p[0], k->cx = p[1], k->cy = p[2];
    } else if (strcmp(model, "SIMPLE_RADIAL") == 0 && n == 8) {
      k->fx = k->fy = p[0], k->cx = p[1], k->cy = p[2], k->k1 = p[3];
    } else {
      fprintf(stderr, "localize_photo: %s line %d: model %s with %d parameters is not supported "
                      "(SIMPLE_PINHOLE f cx cy, PINHOLE fx fy cx cy, SIMPLE_RADIAL f cx cy k)\n",
              list_path, line_no, model, n - 4);
      fclose(f);
      return -1;
    }
    found = 1;
  }
  fclose(f);
  return found;
}

static void print_result(const char* photo, visloc_status status, const visloc_result* r) {
  printf("{\"image\": \"%s\", \"status\": \"%s\"", base_name(photo), visloc_status_string(status));
  if (status == VISLOC_OK) {
    printf(", \"registered\": %d, \"inliers\": %d, \"features\": %d, \"segment\": %d", r->registered, r->inliers,
           r->features, r->segment);
    printf(", \"center\": [%.9f, %.9f, %.9f]", r->center[0], r->center[1], r->center[2]);
    printf(", \"rotation_wxyz\": [%.12f, %.12f, %.12f, %.12f]", r->rotation_wxyz[0], r->rotation_wxyz[1],
           r->rotation_wxyz[2], r->rotation_wxyz[3]);
    if (r->has_enu) printf(", \"enu\": [%.9f, %.9f, %.9f]", r->enu[0], r->enu[1], r->enu[2]);
    printf(", \"focal_px\": %.6f, \"confidence\": %.6f", r->focal_px, r->confidence);
    printf(", \"times_ms\": {\"features\": %.1f, \"retrieval\": %.1f, \"matching\": %.1f, \"ransac\": %.1f, "
           "\"total\": %.1f}",
           r->times.features_ms, r->times.retrieval_ms, r->times.matching_ms, r->times.ransac_ms,
           r->times.total_ms);
  } else {
    printf(", \"error\": \"%s\"", r->error);
  }
  printf(", \"peak_rss_kib\": %ld}\n", peak_rss_kib());
  fflush(stdout);
}

int main(int argc, char** argv) {
  visloc_options options;
  visloc_localizer* localizer = NULL;
  const char* map_dir = NULL;
  const char* intrinsics_list = NULL;
  const char** photos = NULL;
  int photo_count = 0, open_only = 0, failures = 0, i, cache_mib = 0;
  char error[512];
  visloc_status status;

  visloc_options_init(&options);
  photos = (const char**)calloc((size_t)argc, sizeof *photos);
  if (!photos) return 1;
  for (i = 1; i < argc; ++i) {
    const char* a = argv[i];
    const int has_value = i + 1 < argc;
    int ok = 1;
    if (strcmp(a, "--intrinsics") == 0 && has_value) intrinsics_list = argv[++i];
    else if (strcmp(a, "--max-side") == 0 && has_value) ok = parse_int(argv[++i], 0, 1 << 16, &options.max_image_side);
    else if (strcmp(a, "--max-features") == 0 && has_value) ok = parse_int(argv[++i], 1, 1 << 20, &options.max_features);
    else if (strcmp(a, "--cache-mib") == 0 && has_value) {
      ok = parse_int(argv[++i], 1, 1 << 20, &cache_mib);
      options.cache_bytes = (uint64_t)cache_mib << 20;
    } else if (strcmp(a, "--max-segments") == 0 && has_value) ok = parse_int(argv[++i], 1, 64, &options.max_segments);
    else if (strcmp(a, "--threads") == 0 && has_value) ok = parse_int(argv[++i], 1, 256, &options.threads);
    else if (strcmp(a, "--open-only") == 0) open_only = 1;
    else if (a[0] == '-' && a[1] == '-') ok = 0;
    else if (!map_dir) map_dir = a;
    else photos[photo_count++] = a;
    if (!ok) {
      fprintf(stderr, "localize_photo: bad option or value at '%s' (see the comment at the top of "
                      "examples/localize_photo.c)\n", a);
      free(photos);
      return 2;
    }
  }
  if (!map_dir || (photo_count == 0 && !open_only)) {
    fprintf(stderr, "usage: %s MAP_DIR [--intrinsics FILE] [--max-side N] [--max-features N] [--cache-mib N]\n"
                    "       [--max-segments N] [--threads N] [--open-only] PHOTO...\n", argv[0]);
    free(photos);
    return 2;
  }

  printf("{\"event\": \"start\", \"version\": \"%s\", \"peak_rss_kib\": %ld}\n", visloc_version(), peak_rss_kib());
  status = visloc_localizer_open(map_dir, &options, &localizer, error, sizeof error);
  if (status != VISLOC_OK) {
    fprintf(stderr, "localize_photo: cannot open the map: %s: %s\n", visloc_status_string(status), error);
    free(photos);
    return 1;
  }
  printf("{\"event\": \"open\", \"map\": \"%s\", \"peak_rss_kib\": %ld}\n", map_dir, peak_rss_kib());
  fflush(stdout);

  for (i = 0; i < photo_count && !open_only; ++i) {
    visloc_intrinsics k;
    visloc_result result;
    int listed = 0;
    if (intrinsics_list) {
      listed = find_intrinsics(intrinsics_list, base_name(photos[i]), &k);
      if (listed < 0) {
        failures = 1;
        break;
      }
    }
    status = visloc_localize_file(localizer, photos[i], listed ? &k : NULL, &result);
    print_result(photos[i], status, &result);
    if (status != VISLOC_OK) failures = 1;
  }
  visloc_localizer_close(localizer);
  free(photos);
  return failures ? 1 : 0;
}
