/* visloc C API: embed the localizer in an app (Android through JNI, iOS
 * through a bridging header, or any C program). Pure C99; no C++ type and no
 * exception crosses this boundary. docs/embedding.md shows how to link it.
 *
 * Ownership
 *   - visloc_localizer_open() creates a handle; visloc_localizer_close()
 *     destroys it (NULL is allowed). Nothing else allocates for the caller.
 *   - Every other buffer (options, intrinsics, pixels, results, error text)
 *     belongs to the caller and is only read or written during the call; the
 *     library keeps no pointer to it afterwards.
 *   - Strings returned by visloc_status_string() and visloc_version() are
 *     static: never free them.
 *
 * Threading
 *   - visloc_localize_file() and visloc_localize_gray() may be called from
 *     several threads at once on one handle (the map's segments are shared
 *     through one cache; each call has its own working memory).
 *   - visloc_localizer_close() must not run while another call uses the same
 *     handle. Different handles are independent.
 *
 * Errors
 *   Every function returning visloc_status returns VISLOC_OK or an error
 *   code, and writes a message naming the problem (a file, an argument) into
 *   the caller's buffer: `error` for open, `result->error` for localize.
 *   A photo that was processed but could not be placed on the map is not an
 *   error: the call returns VISLOC_OK with result->registered == 0.
 */
#ifndef VISLOC_CAPI_VISLOC_H_
#define VISLOC_CAPI_VISLOC_H_

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* A localizer: one opened map. Opaque; see visloc_localizer_open(). */
typedef struct visloc_localizer visloc_localizer;

typedef enum visloc_status {
  VISLOC_OK = 0,
  VISLOC_INVALID_ARGUMENT = 1, /* a NULL or out-of-range argument or option */
  VISLOC_NOT_FOUND = 2,        /* something named does not exist */
  VISLOC_IO_ERROR = 3,         /* a file cannot be opened or read (a missing map or image) */
  VISLOC_FORMAT_ERROR = 4,     /* a file exists but its content is wrong */
  VISLOC_NOT_IMPLEMENTED = 5,  /* a feature that is not built yet */
  VISLOC_OUT_OF_MEMORY = 6,
  VISLOC_INTERNAL_ERROR = 7    /* a bug in visloc: please report the message */
} visloc_status;

/* The paper's ablation settings (matching and RANSAC variants). */
typedef enum visloc_setting {
  VISLOC_SETTING_1 = 1,      /* full cascade search, classical 1-1 RANSAC */
  VISLOC_SETTING_2 = 2,      /* full cascade search, one-many RANSAC */
  VISLOC_SETTING_3 = 3,      /* prioritized cascade search, one-many RANSAC */
  VISLOC_SETTING_3_PLUS = 4  /* prioritized search, one-many RANSAC with SPRT (default) */
} visloc_setting;

/* Fill with visloc_options_init(), then change what you need. */
typedef struct visloc_options {
  uint64_t cache_bytes;   /* budget of map segments kept in memory (default 512 MiB, at least 1 MiB) */
  int max_segments;       /* candidate segments searched per photo (default 4; when they give no
                             registered pose, the next 4 by votes are searched too) */
  int top_images;         /* retrieval: most similar map images voting for segments (default 20) */
  visloc_setting setting; /* default VISLOC_SETTING_3_PLUS */
  int max_image_side;     /* larger images are downscaled before SIFT (default 800; 0: never) */
  int max_features;       /* strongest SIFT features kept (default 8192) */
  int threads;            /* > 0: sets OpenCV's thread count, which SIFT uses, at visloc_localizer_open
                             (process-wide: it applies to every OpenCV call of the app); default 0:
                             left as the app set it (OpenCV's default: every core) */
  int use_exif_focal;     /* visloc_localize_file: EXIF focal length when no intrinsics (default 1) */
  int min_inliers;        /* a pose is registered at this many inliers (default 12) */
  double min_confidence;  /* ... and at this confidence, in [0, 1] (default: the builtin model's
                             threshold, chosen for a precision >= 99.5 %; 0: inliers only) */
} visloc_options;

/* Intrinsics of the query image. fx and fy are both used (non-square pixels
 * as COLMAP's PINHOLE model; fy / fx within [0.5, 2]); the result's focal_px
 * is fx. Pixel convention: the centre
 * of the top-left pixel is at (0.5, 0.5) (COLMAP's); add 0.5 to a principal
 * point given with that centre at (0, 0). */
typedef struct visloc_intrinsics {
  double fx, fy; /* focal length, pixels */
  double cx, cy; /* principal point, pixels */
  double k1;     /* radial distortion p -> p (1 + k1 |p|^2) of normalized points; 0: none */
} visloc_intrinsics;

typedef struct visloc_stage_times {
  double features_ms, retrieval_ms, matching_ms, ransac_ms, total_ms;
} visloc_stage_times;

/* Written completely by every localize call (zeroed first). */
typedef struct visloc_result {
  int registered;          /* 1: the pose is reliable (min_inliers inliers and min_confidence; on a
                              geo-registered map, its camera not under the street: docs/embedding.md) */
  int segment;             /* map segment of the pose; -1 when no pose */
  int inliers;
  int features;            /* SIFT features of the photo */
  /* cam_from_world: X_cam = R X_world + t, world = the segment's frame
   * (the model's frame for an imported COLMAP model). Camera: +z forward,
   * +x right, +y down. Hamilton quaternion w, x, y, z. */
  double rotation_wxyz[4];
  double translation[3];
  double center[3];        /* camera centre in the segment frame, -R^T t */
  double focal_px;         /* the focal length used or estimated */
  int focal_estimated;     /* 1: the focal length was estimated (no intrinsics, no EXIF) */
  double principal_point_offset[2]; /* focal_estimated: estimated principal point minus the image centre, px */
  int has_enu;             /* the segment is geo-registered: */
  double enu[3];           /*   camera centre, metres east, north, up of the map's origin */
  int has_geo;             /* WGS84 position known: */
  double latitude_deg, longitude_deg, altitude_m; /* altitude above the ellipsoid */
  int has_heading;
  double heading_deg;      /* viewing direction, degrees clockwise from north */
  double confidence;       /* 0-1 score that the pose is right (within 5 m, 10 deg; higher is surer; not a
                              calibrated probability), 0 without a pose */
  /* Uncertainty (has_sigma): the pose refinement's covariance σ times the
   * confidence model's calibration (σ holds 68% of its training errors):
   * centre (sqrt of the covariance's trace) in segment units and rotation;
   * with has_enu also in metres (3D, horizontal, vertical), and with
   * has_heading_sigma the heading's. */
  int has_sigma;
  double position_sigma, rotation_sigma_deg;
  double position_sigma_m, horizontal_sigma_m, vertical_sigma_m;
  int has_heading_sigma;
  double heading_sigma_deg;
  visloc_stage_times times;
  char error[256];         /* empty on VISLOC_OK; otherwise the message (truncated) */
} visloc_result;

/* Library version, e.g. "0.1.0". */
const char* visloc_version(void);

/* A short constant description of a status ("invalid argument", ...);
 * "unknown status" for a value outside the enum. */
const char* visloc_status_string(visloc_status status);

/* Defaults (those of the `visloc localize` command). Does nothing on NULL. */
void visloc_options_init(visloc_options* options);

/* Opens the map in directory `map_dir` (written by `visloc map build` or
 * `visloc map import`). `options` NULL: defaults. On success *out is the new
 * handle; on failure *out is NULL and, when error != NULL and
 * error_size > 0, `error` holds a NUL-terminated message (truncated to
 * error_size). The map's retrieval index is read into memory here; segments
 * are memory-mapped on demand within options->cache_bytes. */
visloc_status visloc_localizer_open(const char* map_dir, const visloc_options* options,
                                    visloc_localizer** out, char* error, size_t error_size);

/* Frees the handle and its memory. NULL is allowed. */
void visloc_localizer_close(visloc_localizer* localizer);

/* Localizes a JPEG or PNG file. `intrinsics` NULL: the EXIF focal length
 * (when options.use_exif_focal and the file has one), else an estimated focal
 * length with the principal point at the image centre. */
visloc_status visloc_localize_file(const visloc_localizer* localizer, const char* image_path,
                                   const visloc_intrinsics* intrinsics, visloc_result* result);

/* Localizes an 8-bit greyscale image in memory: `height` rows of `width`
 * pixels, row r starting at pixels + r * stride_bytes (stride_bytes >= width).
 * From a camera, pass the luma (Y) plane: Android YUV_420_888 plane 0 with its
 * row stride; iOS 420YpCbCr8BiPlanar plane 0 with
 * CVPixelBufferGetBytesPerRowOfPlane(buffer, 0). The pixels are copied before
 * use. `intrinsics` NULL: an estimated focal length. */
visloc_status visloc_localize_gray(const visloc_localizer* localizer, const uint8_t* pixels, int width,
                                   int height, int stride_bytes, const visloc_intrinsics* intrinsics,
                                   visloc_result* result);

#ifdef __cplusplus
} /* extern "C" */
#endif

#endif /* VISLOC_CAPI_VISLOC_H_ */
