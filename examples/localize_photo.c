/* localize_photo: the C API from an app's side (docs/embedding.md,
 * docs/device.md). Opens a map, localizes photos, prints one JSON line per
 * photo (pose, inliers, stage times, peak memory so far), so that runs on
 * two machines (x86-64, aarch64 under qemu) can be compared line by line.
 * A photo named *.pgm (binary 8-bit greyscale) is read here and passed as
 * pixels (visloc_localize_gray), as an app passes a camera frame's luma
 * plane; other files go to visloc_localize_file (JPEG, PNG).
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
    const char* first = line;
    ++line_no;
    if (!strchr(line, '\n') && !feof(f)) {
      fprintf(stderr, "localize_photo: %s line %d: longer than %d characters\n", list_path, line_no,
              (int)sizeof line - 2);
      fclose(f);
      return -1;
    }
    while (*first == ' ' || *first == '\t' || *first == '\r' || *first == '\n') ++first;
    if (*first == '#' || *first == '\0') continue; /* comments and blank lines */
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

/* A JSON string: quotes, backslashes and control bytes escaped. */
static void print_json_string(const char* text) {
  const unsigned char* c = (const unsigned char*)text;
  putchar('"');
  for (; *c; ++c) {
    if (*c == '"' || *c == '\\') printf("\\%c", *c);
    else if (*c < 0x20) printf("\\u%04x", *c);
    else putchar(*c);
  }
  putchar('"');
}

/* A JSON number; null for NaN or infinity, which JSON cannot hold. */
static void print_json_number(const char* format, double v) {
  if (v == v && v - v == 0) printf(format, v);
  else printf("null");
}

static void print_json_numbers(const char* format, const double* v, int n) {
  int i;
  putchar('[');
  for (i = 0; i < n; ++i) {
    if (i) printf(", ");
    print_json_number(format, v[i]);
  }
  putchar(']');
}

/* Reads a binary 8-bit PGM (P5, maxval 255): a camera frame's luma plane as
 * an app would hold it. Returns the pixels (free them) or NULL with a message. */
static int read_pgm_token(FILE* f, long* out) {
  int c = fgetc(f);
  while (c == '#' || c == ' ' || c == '\t' || c == '\r' || c == '\n') {
    if (c == '#') while (c != '\n' && c != EOF) c = fgetc(f);
    c = fgetc(f);
  }
  if (c < '0' || c > '9') return 0;
  *out = 0;
  while (c >= '0' && c <= '9') {
    if (*out > 100000000L) return 0;
    *out = *out * 10 + (c - '0');
    c = fgetc(f);
  }
  return c == ' ' || c == '\t' || c == '\r' || c == '\n'; /* one whitespace after the number */
}

static uint8_t* read_pgm(const char* path, int* width, int* height) {
  FILE* f = fopen(path, "rb");
  long w = 0, h = 0, maxval = 0;
  uint8_t* pixels = NULL;
  if (!f) {
    fprintf(stderr, "localize_photo: cannot open %s\n", path);
    return NULL;
  }
  if (fgetc(f) != 'P' || fgetc(f) != '5' || !read_pgm_token(f, &w) || !read_pgm_token(f, &h) ||
      !read_pgm_token(f, &maxval) || w < 1 || h < 1 || w > 65536 || h > 65536 || maxval != 255) {
    fprintf(stderr, "localize_photo: %s: not a binary 8-bit PGM (P5, maxval 255)\n", path);
    fclose(f);
    return NULL;
  }
  pixels = (uint8_t*)malloc((size_t)w * (size_t)h);
  if (!pixels || fread(pixels, 1, (size_t)w * (size_t)h, f) != (size_t)w * (size_t)h) {
    fprintf(stderr, "localize_photo: %s: %s\n", path, pixels ? "shorter than its header says" : "out of memory");
    free(pixels);
    fclose(f);
    return NULL;
  }
  fclose(f);
  *width = (int)w;
  *height = (int)h;
  return pixels;
}

static int has_suffix(const char* text, const char* suffix) {
  size_t n = strlen(text), k = strlen(suffix);
  return n >= k && strcmp(text + n - k, suffix) == 0;
}

static void print_result(const char* photo, visloc_status status, const visloc_result* r) {
  printf("{\"image\": ");
  print_json_string(base_name(photo));
  printf(", \"status\": \"%s\"", visloc_status_string(status));
  if (status == VISLOC_OK) {
    printf(", \"registered\": %d, \"inliers\": %d, \"features\": %d, \"segment\": %d", r->registered, r->inliers,
           r->features, r->segment);
    printf(", \"center\": ");
    print_json_numbers("%.9f", r->center, 3);
    printf(", \"rotation_wxyz\": ");
    print_json_numbers("%.12f", r->rotation_wxyz, 4);
    if (r->has_enu) {
      printf(", \"enu\": ");
      print_json_numbers("%.9f", r->enu, 3);
    }
    printf(", \"focal_px\": ");
    print_json_number("%.6f", r->focal_px);
    printf(", \"confidence\": ");
    print_json_number("%.6f", r->confidence);
    printf(", \"times_ms\": {\"features\": %.1f, \"retrieval\": %.1f, \"matching\": %.1f, \"ransac\": %.1f, "
           "\"total\": %.1f}",
           r->times.features_ms, r->times.retrieval_ms, r->times.matching_ms, r->times.ransac_ms,
           r->times.total_ms);
  } else {
    printf(", \"error\": ");
    print_json_string(r->error);
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
  printf("{\"event\": \"open\", \"map\": ");
  print_json_string(map_dir);
  printf(", \"peak_rss_kib\": %ld}\n", peak_rss_kib());
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
    if (has_suffix(photos[i], ".pgm")) {
      int width = 0, height = 0;
      uint8_t* pixels = read_pgm(photos[i], &width, &height);
      if (!pixels) {
        failures = 1;
        continue;
      }
      status = visloc_localize_gray(localizer, pixels, width, height, width, listed ? &k : NULL, &result);
      free(pixels);
    } else {
      status = visloc_localize_file(localizer, photos[i], listed ? &k : NULL, &result);
    }
    print_result(photos[i], status, &result);
    if (status != VISLOC_OK) failures = 1;
  }
  visloc_localizer_close(localizer);
  free(photos);
  return failures ? 1 : 0;
}
