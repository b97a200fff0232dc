"""visloc: where a photo was taken, from a street-view map, on the device.

    import visloc
    loc = visloc.Localizer("city_map")
    r = loc.localize("photo.jpg")
    if r.registered:
        print(r.lat, r.lon, r.heading_deg, r.confidence)

Localizer, Map, build_map, import_colmap, fit_blend, evaluate and read_image are the
C++ library's, bound with pybind11 (visloc._core). Errors are visloc.Error
subclasses that are also the matching builtin exceptions:
InvalidArgumentError (ValueError), FormatError (ValueError), NotFoundError
(FileNotFoundError), IoError (OSError), ExternalToolError.
"""

from visloc._core import (  # noqa: F401  (the public API)
    Error,
    ExternalToolError,
    FormatError,
    InvalidArgumentError,
    IoError,
    LocalizationResult,
    Localizer,
    Map,
    NotFoundError,
    Pose,
    Segment,
    build_map,
    evaluate,
    fit_blend,
    import_colmap,
    read_image,
    set_opencv_threads,
)

__all__ = [
    "Error",
    "ExternalToolError",
    "FormatError",
    "InvalidArgumentError",
    "IoError",
    "LocalizationResult",
    "Localizer",
    "Map",
    "NotFoundError",
    "Pose",
    "Segment",
    "build_map",
    "evaluate",
    "fit_blend",
    "import_colmap",
    "read_image",
    "set_opencv_threads",
]
