// visloc._core: the Python bindings (pybind11) behind `import visloc`
// (package_init.py, installed as visloc/__init__.py, re-exports them). They wrap the C++ library directly:
//   Localizer(map_dir, **options)   pipeline/localizer.h; localize() releases the GIL
//   Map(map_dir)                    map/map.h; segment points are numpy views of the mmap
//   build_map / import_colmap / evaluate   what `visloc map build`, `map import`
//                                   and `eval` do, returning their report as a dict
//   read_image                      the pixels localize() decodes from a file
// Options are keyword arguments named like the fields of the C++ option
// structs (the CLI's flags with '_' for '-'); an unknown or ill-typed one
// raises TypeError naming it, a bad value ValueError naming it. Errors of the
// library map to visloc.Error subclasses by kind (see __init__.py).
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "visloc/eval/evaluation_run.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/image/image_io.h"
#include "visloc/map_building/colmap_import.h"
#include "visloc/map/map.h"
#include "visloc/map_building/map_builder.h"
#include "visloc/pipeline/localization_json.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/util/error.h"

namespace py = pybind11;
namespace fs = std::filesystem;

namespace visloc::python {
namespace {

// --- Errors ----------------------------------------------------------------

// The exception classes, created once at import (module state, not a global
// of the library).
struct ErrorClasses {
  py::object base, invalid_argument, io, format, not_found, external_tool;
};
ErrorClasses* error_classes = nullptr;  // owned by the module (never freed: lives as long as the interpreter)

PyObject* error_class(ErrorCode code) {
  const ErrorClasses& c = *error_classes;
  switch (code) {
    case ErrorCode::kInvalidArgument: return c.invalid_argument.ptr();
    case ErrorCode::kIo: return c.io.ptr();
    case ErrorCode::kFormat: return c.format.ptr();
    case ErrorCode::kNotFound: return c.not_found.ptr();
    case ErrorCode::kExternalTool: return c.external_tool.ptr();
    default: return c.base.ptr();
  }
}

[[noreturn]] void raise_error(ErrorCode code, const std::string& message) {
  PyErr_SetString(error_class(code), message.c_str());
  throw py::error_already_set();
}

bool is_path_like(const py::handle& o) {
  return py::isinstance<py::str>(o) || py::isinstance<py::bytes>(o) || py::hasattr(o, "__fspath__");
}

// A str, bytes or os.PathLike as a path; TypeError naming `what` otherwise.
// The file system's bytes (os.fsencode), so that any name os.listdir gives works.
fs::path path_from(const py::object& o, const std::string& what) {
  if (!is_path_like(o))
    throw py::type_error(what + ": expected a path (str, bytes or os.PathLike), got " +
                         py::str(py::type::of(o).attr("__name__")).cast<std::string>());
  const py::bytes b = py::module_::import("os").attr("fsencode")(o);
  return fs::path(std::string(b));
}

// True for Python's and numpy's booleans (which are not numbers here).
bool is_boolean(const py::handle& v) {
  return py::isinstance<py::bool_>(v) || py::str(py::type::of(v).attr("__name__")).cast<std::string>() == "bool_";
}

// An integer (int, numpy integer: anything with __index__ but a boolean) in
// T's range; TypeError / ValueError naming `what`.
template <typename T>
T integer_from(const py::handle& v, const std::string& what) {
  if (is_boolean(v)) throw py::type_error(what + ": expected an integer, got a boolean");
  PyObject* index = PyNumber_Index(v.ptr());
  if (index == nullptr) {
    PyErr_Clear();
    throw py::type_error(what + ": expected an integer, got " + py::str(py::type::of(v).attr("__name__")).cast<std::string>());
  }
  const py::object i = py::reinterpret_steal<py::object>(index);
  int overflow = 0;
  const long long value = PyLong_AsLongLongAndOverflow(i.ptr(), &overflow);
  bool in_range = overflow == 0;
  if (in_range) {
    if constexpr (std::is_unsigned_v<T>) in_range = value >= 0 && static_cast<unsigned long long>(value) <= std::numeric_limits<T>::max();
    else in_range = value >= static_cast<long long>(std::numeric_limits<T>::min()) && value <= static_cast<long long>(std::numeric_limits<T>::max());
  }
  if (!in_range) {
    if (overflow > 0 && std::is_same_v<T, uint64_t>) {  // above 2^63: only an unsigned 64-bit field holds it
      const unsigned long long u = PyLong_AsUnsignedLongLong(i.ptr());
      if (!PyErr_Occurred()) return static_cast<T>(u);
      PyErr_Clear();
    }
    raise_error(ErrorCode::kInvalidArgument, what + " must be an integer in [" + std::to_string(std::numeric_limits<T>::min()) +
                                                 ", " + std::to_string(std::numeric_limits<T>::max()) + "], got " +
                                                 py::str(v).cast<std::string>());
  }
  return static_cast<T>(value);
}

// A finite real number (int, float, numpy number; not a boolean or a string).
double finite_number_from(const py::handle& v, const std::string& what) {
  if (is_boolean(v) || py::isinstance<py::str>(v) || py::isinstance<py::bytes>(v))
    throw py::type_error(what + ": expected a number, got " + py::str(py::type::of(v).attr("__name__")).cast<std::string>());
  const double d = PyFloat_AsDouble(v.ptr());
  if (d == -1.0 && PyErr_Occurred()) {
    PyErr_Clear();
    throw py::type_error(what + ": expected a number, got " + py::str(py::type::of(v).attr("__name__")).cast<std::string>());
  }
  if (!std::isfinite(d))
    raise_error(ErrorCode::kInvalidArgument, what + " must be a finite number, got " + py::str(v).cast<std::string>());
  return d;
}

// --- Keyword options -------------------------------------------------------

// Takes keyword arguments one by one into option fields; finish() rejects the
// ones nobody took. Numbers must be finite.
class Kwargs {
 public:
  Kwargs(const py::kwargs& kwargs, std::string where) : where_(std::move(where)) {
    for (auto item : kwargs) values_[item.first.cast<std::string>()] = py::reinterpret_borrow<py::object>(item.second);
  }

  template <typename T>
  bool take(const std::string& name, T& field) {
    known_.insert(name);
    auto it = values_.find(name);
    if (it == values_.end() || it->second.is_none()) {
      if (it != values_.end()) values_.erase(it);
      return false;
    }
    py::object value = it->second;
    values_.erase(it);
    try {
      if constexpr (std::is_same_v<T, bool>) {
        if (!py::isinstance<py::bool_>(value)) throw py::cast_error();
        field = value.cast<bool>();
      } else if constexpr (std::is_integral_v<T>) {
        field = integer_from<T>(value, where_ + ": " + name);
      } else if constexpr (std::is_floating_point_v<T>) {
        field = static_cast<T>(finite_number_from(value, where_ + ": " + name));
      } else if constexpr (std::is_same_v<T, fs::path>) {
        field = path_from(value, where_ + ": option '" + name + "'");
      } else {
        if (!py::isinstance<py::str>(value)) throw py::cast_error();
        field = value.cast<T>();
      }
    } catch (const py::cast_error&) {
      throw py::type_error(where_ + ": option '" + name + "' has the wrong type (" +
                           py::str(py::type::of(value).attr("__name__")).cast<std::string>() + ")");
    } catch (const py::error_already_set& e) {
      if (e.matches(PyExc_TypeError)) {
        throw py::type_error(where_ + ": option '" + name + "' has the wrong type (" +
                             py::str(py::type::of(value).attr("__name__")).cast<std::string>() + ")");
      }
      throw;
    }
    return true;
  }

  // A string option restricted to `choices`.
  bool take_choice(const std::string& name, std::string& field, const std::vector<std::string>& choices) {
    if (!take(name, field)) return false;
    for (const auto& c : choices)
      if (c == field) return true;
    std::string list;
    for (const auto& c : choices) list += (list.empty() ? "" : ", ") + ("'" + c + "'");
    raise_error(ErrorCode::kInvalidArgument, where_ + ": " + name + " must be one of " + list + ", got '" + field + "'");
  }

  // The raw object of an option with a custom conversion (None when absent).
  py::object take_object(const std::string& name) {
    known_.insert(name);
    auto it = values_.find(name);
    if (it == values_.end()) return py::none();
    py::object v = it->second;
    values_.erase(it);
    return v;
  }

  void finish() const {
    if (values_.empty()) return;
    std::string known;
    for (const auto& k : known_) known += (known.empty() ? "" : ", ") + k;
    throw py::type_error(where_ + ": unknown option '" + values_.begin()->first + "' (known: " + known + ")");
  }

  const std::string& where() const { return where_; }

 private:
  std::string where_;
  std::map<std::string, py::object> values_;
  std::set<std::string> known_;
};

void take_sift_options(Kwargs& k, SiftOptions& o) {
  k.take("max_image_side", o.max_image_side);
  k.take("max_features", o.max_features);
  k.take("contrast_threshold", o.contrast_threshold);
  k.take("root_sift", o.root_sift);
  k.take("max_pixels", o.image.max_pixels);
}

// LocalizerOptions from keywords, named as the CLI's localizer flags.
void take_localizer_options(Kwargs& k, LocalizerOptions& o) {
  std::string setting;
  if (k.take_choice("setting", setting, {"1", "2", "3", "3+"})) o.setting = parse_paper_setting(setting);
  k.take("top_images", o.top_images);
  k.take("max_segments", o.max_segments);
  k.take("fallback_segments", o.fallback_segments);
  std::string segment_votes;
  if (k.take_choice("segment_votes", segment_votes, {"auto", "images", "points", "both"}))
    o.segment_votes = parse_segment_vote_source(segment_votes);
  k.take("vote_points", o.point_votes.points_per_segment);
  k.take("vote_max_points", o.point_votes.max_points);
  k.take("under_street_check", o.under_street.enabled);
  k.take("map_point_uncertainty", o.map_point_uncertainty);
  k.take("max_drop_below_map", o.under_street.max_drop_m);
  k.take("vote_chance_normalization", o.point_votes.normalize_by_chance);
  k.take("vote_radius", o.point_votes.probe_radius);
  k.take("vote_ratio", o.point_votes.distinct_ratio);
  k.take("accept_inliers", o.accept_inliers);
  k.take("early_stop", o.search.early_stop);
  k.take("lut_flips", o.search.lut_flips);
  k.take("lut_flips_min_list", o.search.lut_flips_min_list);
  {
    // 'map' (the map's fitted weight, the default) or a weight in [0, 1].
    py::object blend = k.take_object("hash_blend");
    if (!blend.is_none()) {
      if (py::isinstance<py::str>(blend)) {
        const std::string text = blend.cast<std::string>();
        if (text != "map")
          raise_error(ErrorCode::kInvalidArgument,
                      "Localizer: hash_blend must be 'map' or a number in [0, 1], got '" + text + "'");
        o.hash_blend_source = HashBlendSource::kMap;
      } else {
        // A number (int, float, numpy scalar); a bool, bytes or anything else is a TypeError.
        const double w = finite_number_from(blend, "Localizer: hash_blend ('map' or a number in [0, 1])");
        if (!(w >= 0 && w <= 1))
          raise_error(ErrorCode::kInvalidArgument,
                      "Localizer: hash_blend must be 'map' or a number in [0, 1], got " + std::to_string(w));
        o.hash_blend_source = HashBlendSource::kGiven;
        o.search.hash_blend_weight = static_cast<float>(w);
      }
    }
  }
  k.take("full_search_fallback", o.full_search_fallback);
  k.take("threshold_px", o.ransac.threshold_px);
  k.take("min_inliers", o.ransac.min_inliers);
  k.take("min_confidence", o.min_confidence);
  k.take("use_exif_focal", o.use_exif_focal);
  k.take("seed", o.ransac.seed);
  double cache_mib = static_cast<double>(o.cache_bytes) / (1 << 20);
  if (k.take("cache_mib", cache_mib)) {
    if (!(cache_mib >= 1 && cache_mib <= double(1ull << 40)))
      raise_error(ErrorCode::kInvalidArgument, k.where() + ": cache_mib must be in [1, 2^40], got " + std::to_string(cache_mib));
    o.cache_bytes = static_cast<uint64_t>(cache_mib * (1 << 20));
  }
  take_sift_options(k, o.sift);
}

// Runs a library call, turning visloc::Error into the Python classes.
template <typename F>
auto translate_errors(F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const Error& e) {
    raise_error(e.code(), e.what());
  }
}

// --- JSON ↔ Python -----------------------------------------------------------

py::object to_python(const nlohmann::json& j) {
  switch (j.type()) {
    case nlohmann::json::value_t::null: return py::none();
    case nlohmann::json::value_t::boolean: return py::bool_(j.get<bool>());
    case nlohmann::json::value_t::number_integer: return py::int_(j.get<int64_t>());
    case nlohmann::json::value_t::number_unsigned: return py::int_(j.get<uint64_t>());
    case nlohmann::json::value_t::number_float: return py::float_(j.get<double>());
    case nlohmann::json::value_t::string: return py::str(j.get_ref<const std::string&>());
    case nlohmann::json::value_t::array: {
      py::list l;
      for (const auto& v : j) l.append(to_python(v));
      return l;
    }
    case nlohmann::json::value_t::object: {
      py::dict d;
      for (const auto& [key, v] : j.items()) d[py::str(key)] = to_python(v);
      return d;
    }
    default: return py::none();
  }
}

// --- Images and intrinsics ----------------------------------------------------

// A numpy uint8 array H×W (grey), H×W×3 (RGB, or BGR with bgr=True) or H×W×4
// (RGBA / BGRA, alpha ignored) as a
// GrayImage (copied: the GIL is released afterwards).
GrayImage gray_from_array(const py::array& input, bool bgr) {
  if (!py::isinstance<py::array_t<uint8_t>>(input) || input.dtype().kind() != 'u' || input.itemsize() != 1)
    raise_error(ErrorCode::kInvalidArgument,
                "localize: the image array must have dtype uint8, got " + py::str(input.dtype()).cast<std::string>());
  const auto arr = py::array_t<uint8_t, py::array::c_style | py::array::forcecast>::ensure(input);
  if (!arr) raise_error(ErrorCode::kInvalidArgument, "localize: cannot read the image array");
  const int nd = static_cast<int>(arr.ndim());
  if (nd != 2 && !(nd == 3 && (arr.shape(2) == 1 || arr.shape(2) == 3 || arr.shape(2) == 4)))
    raise_error(ErrorCode::kInvalidArgument, "localize: the image array must be H×W, H×W×3 or H×W×4, got " +
                                                 std::to_string(nd) + " dimensions" +
                                                 (nd == 3 ? " with " + std::to_string(arr.shape(2)) + " channels" : ""));
  const py::ssize_t h = arr.shape(0), w = arr.shape(1);
  if (h < 1 || w < 1 || h > (1 << 16) || w > (1 << 16))
    raise_error(ErrorCode::kInvalidArgument,
                "localize: bad image size " + std::to_string(w) + "x" + std::to_string(h));
  GrayImage g;
  g.width = static_cast<int>(w);
  g.height = static_cast<int>(h);
  g.pixels.resize(static_cast<size_t>(w) * static_cast<size_t>(h));
  if (nd == 2 || arr.shape(2) == 1) {
    std::memcpy(g.pixels.data(), arr.data(), g.pixels.size());
  } else {
    const bool alpha = arr.shape(2) == 4;  // the alpha channel is ignored
    const cv::Mat color(g.height, g.width, alpha ? CV_8UC4 : CV_8UC3, const_cast<uint8_t*>(arr.data()));
    cv::Mat gray(g.height, g.width, CV_8UC1, g.pixels.data());
    cv::cvtColor(color, gray, alpha ? (bgr ? cv::COLOR_BGRA2GRAY : cv::COLOR_RGBA2GRAY)
                                    : (bgr ? cv::COLOR_BGR2GRAY : cv::COLOR_RGB2GRAY));
  }
  return g;
}

// intrinsics: None; a focal length in pixels (the rest from the image); a
// dict {focal, fy, cx, cy, width, height, k1} (focal required; focal is fx,
// fy defaults to it); or a COLMAP
// camera (model, width, height, params).
std::optional<PinholeCamera> intrinsics_from_python(const py::object& o) {
  if (o.is_none()) return std::nullopt;
  const std::string where = "localize: intrinsics";
  PinholeCamera c;
  try {
    const bool number = !is_boolean(o) && !py::isinstance<py::str>(o) && !py::isinstance<py::bytes>(o) &&
                        (py::isinstance<py::float_>(o) || py::isinstance<py::int_>(o) || py::hasattr(o, "__float__"));
    if (number) {
      c.focal = finite_number_from(o, where + ": the focal length");
      c.has_focal = true;
      if (!(std::isfinite(c.focal) && c.focal > 0))
        raise_error(ErrorCode::kInvalidArgument, where + ": the focal length must be a positive finite number");
      return c;
    }
    if (py::isinstance<py::dict>(o)) {
      const py::dict d = o.cast<py::dict>();
      static const std::set<std::string> keys = {"focal", "fy", "cx", "cy", "width", "height", "k1"};
      for (auto item : d) {
        const std::string key = py::str(item.first).cast<std::string>();
        if (!keys.count(key))
          raise_error(ErrorCode::kInvalidArgument,
                      where + ": unknown key '" + key + "' (focal, fy, cx, cy, width, height, k1)");
      }
      if (!d.contains("focal")) raise_error(ErrorCode::kInvalidArgument, where + ": 'focal' is required");
      c.focal = finite_number_from(d["focal"], where + ": focal");
      c.has_focal = true;
      const bool has_size = d.contains("width") || d.contains("height");
      const bool has_pp = d.contains("cx") || d.contains("cy");
      if (has_size != has_pp || (has_size && !(d.contains("width") && d.contains("height") && d.contains("cx") && d.contains("cy"))))
        raise_error(ErrorCode::kInvalidArgument, where + ": give width, height, cx and cy together, or only focal");
      if (has_size) {
        c.width = integer_from<int>(d["width"], where + ": width");
        c.height = integer_from<int>(d["height"], where + ": height");
        c.cx = finite_number_from(d["cx"], where + ": cx");
        c.cy = finite_number_from(d["cy"], where + ": cy");
      }
      if (d.contains("k1")) c.k1 = finite_number_from(d["k1"], where + ": k1");
      if (!(std::isfinite(c.focal) && c.focal > 0))
        raise_error(ErrorCode::kInvalidArgument, where + ": focal must be a positive finite number");
      if (d.contains("fy")) {
        c.aspect = finite_number_from(d["fy"], where + ": fy") / c.focal;
        if (!(c.aspect >= PinholeCamera::kMinAspect && c.aspect <= PinholeCamera::kMaxAspect))
          raise_error(ErrorCode::kInvalidArgument, where + ": fy / focal must be in [0.5, 2]");
      }
      if (has_size) c.validate();
      return c;
    }
    if (py::isinstance<py::tuple>(o) || py::isinstance<py::list>(o)) {
      const py::sequence s = o.cast<py::sequence>();
      if (s.size() != 4)
        raise_error(ErrorCode::kInvalidArgument, where + ": a COLMAP camera is (model, width, height, params)");
      std::vector<double> params;
      for (auto p : s[3].cast<py::sequence>()) params.push_back(finite_number_from(p, where + ": a parameter"));
      return PinholeCamera::from_colmap(s[0].cast<std::string>(), integer_from<int>(s[1], where + ": width"),
                                        integer_from<int>(s[2], where + ": height"), params);
    }
  } catch (const py::cast_error&) {
    raise_error(ErrorCode::kInvalidArgument, where + ": a value has the wrong type");
  } catch (const Error& e) {
    raise_error(e.code(), where + ": " + e.what());
  }
  raise_error(ErrorCode::kInvalidArgument,
              where + ": expected None, a focal length, a dict or (model, width, height, params), got " +
                  py::str(py::type::of(o).attr("__name__")).cast<std::string>());
}

// --- Results -----------------------------------------------------------------

py::array_t<double> vector_array(const double* v, size_t n) {
  py::array_t<double> a(static_cast<py::ssize_t>(n));
  std::memcpy(a.mutable_data(), v, n * sizeof(double));
  return a;
}

struct Pose {
  CameraPose cam_from_world;
};

struct Result {
  LocalizationResult r;
};

// --- Map -----------------------------------------------------------------------

struct PySegment {
  std::shared_ptr<const Map> map;
  std::unique_ptr<Segment> segment;
};

class PyMap {
 public:
  explicit PyMap(const fs::path& dir) : map_(std::make_shared<Map>(Map::open(dir))) {
    segments_.resize(map_->manifest().segments.size());
  }
  const Map& map() const { return *map_; }
  size_t size() const { return segments_.size(); }
  // A Python index (an integer, negative from the end) as a position.
  size_t position(const py::object& index) const {
    const long long i = integer_from<long long>(index, "Map: segment index");
    const long long n = static_cast<long long>(segments_.size());
    if (i < -n || i >= n)
      throw py::index_error("segment index " + std::to_string(i) + " out of range (" + std::to_string(n) + " segments)");
    return static_cast<size_t>(i < 0 ? i + n : i);
  }
  // Segments are mapped on first use and kept while the Map lives.
  std::shared_ptr<PySegment> segment(size_t index) {
    if (index >= segments_.size())
      throw py::index_error("segment index " + std::to_string(index) + " out of range (" +
                            std::to_string(segments_.size()) + " segments)");
    if (!segments_[index]) {
      auto s = std::make_shared<PySegment>();
      s->map = map_;
      s->segment = map_->open_segment(index);
      segments_[index] = s;
    }
    return segments_[index];
  }

 private:
  std::shared_ptr<const Map> map_;
  std::vector<std::shared_ptr<PySegment>> segments_;
};

py::dict image_dict(const SegmentImage& im) {
  py::dict d;
  d["name"] = im.name;
  d["camera_model_id"] = im.camera_model_id;
  d["width"] = im.width;
  d["height"] = im.height;
  d["camera_params"] = vector_array(im.camera_params.data(), im.camera_params.size());
  d["qvec"] = vector_array(im.cam_from_world_q_wxyz.data(), 4);
  d["tvec"] = vector_array(im.cam_from_world_t.data(), 3);
  return d;
}

py::object similarity_dict(const std::optional<Similarity3d>& s) {
  if (!s) return py::none();
  py::dict d;
  d["scale"] = s->scale;
  py::array_t<double> r({3, 3});
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r.mutable_at(i, j) = s->rotation(i, j);
  d["rotation"] = r;
  d["translation"] = vector_array(s->translation.data(), 3);
  return d;
}

// --- Map building -----------------------------------------------------------------

std::string number_text(double v) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.17g", v);
  return text;
}

// `--point-coordinates`' choice names (the option table's).
const char* point_coordinates_name(PointCoordinates c) {
  return c == PointCoordinates::kInt16 ? "int16" : c == PointCoordinates::kFloat32 ? "float32" : "auto";
}

// The keyword `pq_bytes` (16 or 32), if given, into `bytes`.
bool take_pq_bytes(Kwargs& k, const std::string& where, int& bytes) {
  int given = 0;
  if (!k.take("pq_bytes", given)) return false;
  if (!valid_pq_subvectors(given))
    raise_error(ErrorCode::kInvalidArgument, where + ": pq_bytes must be 16 or 32, got " + std::to_string(given));
  bytes = given;
  return true;
}

// The keywords `pq_quantizer` ('product' or 'residual'; into `quantizer`,
// returns whether it was given), `pq_residual_splits` (1, 2 or 4) and
// `pq_residual_beam` (1 to 64), each left empty when not given.
bool take_pq_quantizer(Kwargs& k, const std::string& where, PqQuantizer& quantizer, std::optional<int>& splits,
                       std::optional<int>& beam) {
  if (int given = 0; k.take("pq_residual_splits", given)) {
    if (!valid_residual_splits(given))
      raise_error(ErrorCode::kInvalidArgument,
                  where + ": pq_residual_splits must be 1, 2 or 4, got " + std::to_string(given));
    splits = given;
  }
  if (int given = 0; k.take("pq_residual_beam", given)) {
    if (given < 1 || given > kResidualMaxBeam)
      raise_error(ErrorCode::kInvalidArgument, where + ": pq_residual_beam must be in [1, " +
                                                   std::to_string(kResidualMaxBeam) + "], got " +
                                                   std::to_string(given));
    beam = given;
  }
  std::string name;
  if (!k.take_choice("pq_quantizer", name, {"product", "residual"})) return false;
  quantizer = name == "residual" ? PqQuantizer::kResidual : PqQuantizer::kProduct;
  return true;
}

// The keyword `pq_residual_kmeans` ('progressive' or 'plain'), if given.
void take_residual_kmeans(Kwargs& k, PqTrainingOptions& pq) {
  std::string name;
  if (k.take_choice("pq_residual_kmeans", name, {"progressive", "plain"}))
    pq.residual_progressive_dim = name == "progressive";
}

// The keyword `point_coordinates` ('auto', 'float32', 'int16'), if given.
void take_point_coordinates(Kwargs& k, SegmentWriteOptions& o) {
  std::string name;
  if (k.take_choice("point_coordinates", name, {"auto", "float32", "int16"}))
    o.coordinates = name == "int16"     ? PointCoordinates::kInt16
                    : name == "float32" ? PointCoordinates::kFloat32
                                        : PointCoordinates::kAuto;
  k.take("point_uncertainty", o.point_uncertainty);
}

// The `visloc map build` arguments that give these options, recorded in
// MAP/work/build.json as the CLI records its own, so that `visloc map
// build-segment` (a Slurm task, or a segment rebuilt by hand) builds a map
// started from Python with the same options. Paths absolute.
nlohmann::json build_record(const MapBuildOptions& o, const fs::path& map_dir) {
  auto abs = [](const fs::path& p) { return fs::absolute(p).string(); };
  std::vector<std::string> a = {"--images", abs(o.images_dir), "--out", abs(map_dir)};
  auto add = [&a](const std::string& flag, const std::string& value) {
    a.push_back(flag);
    a.push_back(value);
  };
  add("--gps", o.gps_csv.empty() ? std::string("exif") : abs(o.gps_csv));
  if (o.gps_lists_subset) a.push_back("--gps-subset");
  add("--poses", o.poses == PoseSource::kKnown ? "known" : "sfm");
  if (!o.known_poses.empty()) add("--known-poses", abs(o.known_poses));
  if (!o.known_intrinsics.empty()) add("--known-intrinsics", abs(o.known_intrinsics));
  add("--matcher", std::string(to_string(o.matcher)));
  add("--sampson", number_text(o.guided.max_sampson_px));
  const RansacVariant pair_ransac = o.pair_verification.estimation.variant;  // --pair-ransac's choice names
  add("--pair-ransac", pair_ransac == RansacVariant::kClassic11      ? "classic"
                       : pair_ransac == RansacVariant::kOneManyFixed ? "1m"
                                                                     : "1m-sprt");
  add("--pair-threshold", number_text(o.pair_verification.estimation.threshold_px));
  add("--jobs", std::to_string(o.jobs));
  add("--colmap", o.colmap.binary);
  add("--colmap-threads", std::to_string(o.colmap.threads));
  add("--exhaustive-max", std::to_string(o.exhaustive_max_images));
  add("--spatial-neighbors", std::to_string(o.colmap.spatial_max_neighbors));
  add("--min-placemarks", std::to_string(o.plan.min_placemarks));
  add("--max-placemarks", std::to_string(o.plan.max_placemarks));
  add("--overlap", std::to_string(o.plan.overlap));
  add("--placemark-radius", number_text(o.plan.placemark_radius));
  if (o.plan.order == PlacemarkOrder::kChain) a.push_back("--chain-order");
  add("--registration-threshold", number_text(o.registration.inlier_threshold));
  if (!o.build_retrieval) a.push_back("--no-retrieval");
  if (o.fit_hash_blend) a.push_back(*o.fit_hash_blend ? "--fit-blend" : "--no-fit-blend");
  add("--retrieval-dims", std::to_string(o.embedding.output_dims));
  add("--pq-training-images", std::to_string(o.pq_training_images));
  if (o.hash_rotation) add("--hash-rotation", to_string(*o.hash_rotation));
  add("--point-coordinates", point_coordinates_name(o.segment_file.coordinates));
  if (o.segment_file.point_uncertainty) a.push_back("--point-uncertainty");
  if (o.pq_code_bytes) add("--pq-bytes", std::to_string(*o.pq_code_bytes));
  if (o.pq_quantizer) add("--pq-quantizer", to_string(*o.pq_quantizer));
  if (o.pq_residual_splits) add("--pq-residual-splits", std::to_string(*o.pq_residual_splits));
  if (o.pq_residual_beam) add("--pq-residual-beam", std::to_string(*o.pq_residual_beam));
  add("--pq-residual-kmeans", o.pq.residual_progressive_dim ? "progressive" : "plain");
  add("--max-side", std::to_string(o.sift.max_image_side));
  add("--max-features", std::to_string(o.sift.max_features));
  add("--contrast-threshold", number_text(o.sift.contrast_threshold));
  if (!o.sift.root_sift) a.push_back("--no-root-sift");
  add("--max-pixels", std::to_string(o.sift.image.max_pixels));
  return {{"version", 1}, {"cwd", fs::current_path().string()}, {"args", a}, {"by", "python visloc.build_map"}};
}

// --- Module ----------------------------------------------------------------------

std::vector<std::string> names_from(const py::object& o, const std::string& what) {
  if (o.is_none()) return {};
  if (is_path_like(o)) {
    const fs::path p = path_from(o, what);
    return translate_errors([&] { return read_name_list(p); });
  }
  try {
    return o.cast<std::vector<std::string>>();
  } catch (const py::cast_error&) {
    throw py::type_error(what + ": a list of names or a file of names, one per line");
  }
}

// The visloc.Error classes by kind, and the translator that raises them for the library's errors.
void bind_errors(py::module_& m) {
  // Error classes by kind; each is also a matching builtin exception.
  auto builtins = py::module_::import("builtins");
  auto make = [&](const char* name, py::tuple bases, const char* doc) {
    py::dict ns;
    ns["__doc__"] = doc;
    ns["__module__"] = "visloc";
    py::object cls = builtins.attr("type")(name, bases, ns);
    m.attr(name) = cls;
    return cls;
  };
  error_classes = new ErrorClasses;
  error_classes->base = make("Error", py::make_tuple(builtins.attr("RuntimeError")),
                             "A visloc error: bad input, a bad file, a failed external tool.");
  error_classes->invalid_argument = make("InvalidArgumentError", py::make_tuple(error_classes->base, builtins.attr("ValueError")),
                                         "A bad option or argument value.");
  error_classes->io = make("IoError", py::make_tuple(error_classes->base, builtins.attr("OSError")),
                           "A file cannot be opened, read or written.");
  error_classes->format = make("FormatError", py::make_tuple(error_classes->base, builtins.attr("ValueError")),
                               "A file exists but its content is wrong.");
  error_classes->not_found = make("NotFoundError", py::make_tuple(error_classes->base, builtins.attr("FileNotFoundError")),
                                  "Something named does not exist.");
  error_classes->external_tool = make("ExternalToolError", py::make_tuple(error_classes->base),
                                      "An external program (COLMAP, Slurm) failed.");
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const Error& e) {
      PyErr_SetString(error_class(e.code()), e.what());
    }
  });
}

// visloc.Pose.
void bind_pose(py::module_& m) {
  py::class_<Pose>(m, "Pose", "A camera pose, world-to-camera (COLMAP's convention), in the segment's frame.")
      .def_property_readonly("qvec", [](const Pose& p) {
        const auto q = p.cam_from_world.q_wxyz();
        return vector_array(q.data(), 4);
      }, "Rotation quaternion (w, x, y, z), numpy float64[4].")
      .def_property_readonly("tvec", [](const Pose& p) { return vector_array(p.cam_from_world.translation.data(), 3); },
                             "Translation, numpy float64[3].")
      .def_property_readonly("cam_from_world", [](const Pose& p) {
        const Eigen::Matrix<double, 3, 4> M = p.cam_from_world.matrix();
        py::array_t<double> a({3, 4});
        for (int i = 0; i < 3; ++i)
          for (int j = 0; j < 4; ++j) a.mutable_at(i, j) = M(i, j);
        return a;
      }, "[R | t] as a numpy float64 3×4 matrix.")
      .def_property_readonly("center", [](const Pose& p) {
        const Eigen::Vector3d c = p.cam_from_world.center();
        return vector_array(c.data(), 3);
      }, "Camera centre in the segment's frame, numpy float64[3].")
      .def("__repr__", [](const Pose& p) {
        const auto q = p.cam_from_world.q_wxyz();
        const auto& t = p.cam_from_world.translation;
        return "Pose(qvec=[" + std::to_string(q[0]) + ", " + std::to_string(q[1]) + ", " + std::to_string(q[2]) + ", " +
               std::to_string(q[3]) + "], tvec=[" + std::to_string(t.x()) + ", " + std::to_string(t.y()) + ", " +
               std::to_string(t.z()) + "])";
      });
}

// visloc.LocalizationResult.
void bind_localization_result(py::module_& m) {
  py::class_<Result>(m, "LocalizationResult", "One photo's localization (the CLI's JSON line as attributes).")
      .def_property_readonly("image", [](const Result& r) { return r.r.image; })
      .def_property_readonly("registered", [](const Result& r) { return r.r.registered; })
      .def_property_readonly("segment", [](const Result& r) { return r.r.segment; },
                             "Id of the segment of the best pose (-1: no pose).")
      .def_property_readonly("pose", [](const Result& r) -> py::object {
        if (r.r.segment < 0) return py::none();
        return py::cast(Pose{r.r.cam_from_segment});
      }, "The best pose (also when not registered), or None.")
      .def_property_readonly("center_enu", [](const Result& r) -> py::object {
        if (!r.r.center_enu) return py::none();
        return vector_array(r.r.center_enu->data(), 3);
      }, "Camera centre in the map's ENU frame (metres), or None without geo-registration.")
      .def_property_readonly("lat", [](const Result& r) -> py::object {
        return r.r.position ? py::object(py::float_(r.r.position->lat)) : py::none();
      })
      .def_property_readonly("lon", [](const Result& r) -> py::object {
        return r.r.position ? py::object(py::float_(r.r.position->lon)) : py::none();
      })
      .def_property_readonly("alt", [](const Result& r) -> py::object {
        return r.r.position ? py::object(py::float_(r.r.position->alt)) : py::none();
      })
      .def_property_readonly("heading_deg", [](const Result& r) -> py::object {
        return r.r.heading_deg ? py::object(py::float_(*r.r.heading_deg)) : py::none();
      }, "Compass heading of the camera's viewing direction, degrees clockwise from north.")
      .def_property_readonly("inliers", [](const Result& r) { return r.r.inliers; })
      .def_property_readonly("confidence", [](const Result& r) { return r.r.confidence; },
                             "Probability in [0, 1] that the pose is right (0 without a pose).")
      .def_property_readonly("focal_px", [](const Result& r) { return r.r.focal_px; })
      .def_property_readonly("focal_estimated", [](const Result& r) { return r.r.focal_estimated; })
      .def_property_readonly("features", [](const Result& r) { return r.r.features; })
      .def_property_readonly("times_ms", [](const Result& r) {
        py::dict d;
        d["features"] = r.r.times.features;
        d["retrieval"] = r.r.times.retrieval;
        d["matching"] = r.r.times.matching;
        d["ransac"] = r.r.times.ransac;
        d["total"] = r.r.times.total;
        return d;
      }, "Milliseconds per stage: features, retrieval, matching, ransac, total.")
      .def("to_dict", [](const Result& r) { return to_python(to_json(r.r)); },
           "Everything, as the CLI's JSON line (`visloc localize`).")
      .def("__repr__", [](const Result& r) {
        return "LocalizationResult(image='" + r.r.image + "', registered=" + (r.r.registered ? "True" : "False") +
               ", inliers=" + std::to_string(r.r.inliers) + ", confidence=" + std::to_string(r.r.confidence) + ")";
      });
}

// visloc.Localizer.
void bind_localizer(py::module_& m) {
  py::class_<Localizer>(m, "Localizer", R"doc(A map opened for localization.

Localizer(map_dir, **options): options are LocalizerOptions fields, named as
the `visloc localize` flags: setting ('1', '2', '3', '3+'), top_images,
max_segments, fallback_segments, segment_votes ('auto', 'points', 'images',
'both'), vote_points, vote_max_points, vote_radius, vote_ratio, vote_chance_normalization, accept_inliers, early_stop, lut_flips, lut_flips_min_list,
hash_blend ('map', the default: the weight the map stores, or a number in [0, 1]),
full_search_fallback, threshold_px, min_inliers, min_confidence, under_street_check (False: --allow-under-street),
map_point_uncertainty (False: --no-map-point-uncertainty),
max_drop_below_map, use_exif_focal, seed, cache_mib, max_image_side,
max_features, contrast_threshold, root_sift, max_pixels. OpenCV's thread count,
which SIFT uses, is process-wide: see visloc.set_opencv_threads.
Thread-safe: localize() releases the GIL, so threads localize in parallel.)doc")
      .def(py::init([](const py::object& map_dir, const py::kwargs& kwargs) {
             Kwargs k(kwargs, "Localizer");
             LocalizerOptions o;
             take_localizer_options(k, o);
             k.finish();
             const fs::path dir = path_from(map_dir, "Localizer: map_dir");
             return translate_errors([&] {
               o.validate();
               py::gil_scoped_release release;
               return std::make_unique<Localizer>(dir, o);
             });
           }),
           py::arg("map_dir"))
      .def(
          "localize",
          [](const Localizer& loc, const py::object& image, const py::object& intrinsics, bool bgr) {
            const std::optional<PinholeCamera> cam = intrinsics_from_python(intrinsics);
            Result out;
            if (py::isinstance<py::array>(image) || (!is_path_like(image) && py::hasattr(image, "__array__"))) {
              // numpy arrays and what converts to one (e.g. a PIL image).
              const py::array arr = py::module_::import("numpy").attr("asarray")(image);
              GrayImage g = gray_from_array(arr, bgr);
              translate_errors([&] {
                py::gil_scoped_release release;
                out.r = loc.localize_image(g, cam);
              });
              return out;
            }
            if (!is_path_like(image))
              throw py::type_error("localize: expected a path or a numpy uint8 array, got " +
                                   py::str(py::type::of(image).attr("__name__")).cast<std::string>());
            const fs::path path = path_from(image, "localize: image");
            if (!fs::exists(path)) raise_error(ErrorCode::kNotFound, path.string() + ": no such file");
            translate_errors([&] {
              py::gil_scoped_release release;
              out.r = loc.localize_file(path, cam);
            });
            if (!out.r.error.empty()) raise_error(out.r.error_code, out.r.error);
            return out;
          },
          py::arg("image"), py::arg("intrinsics") = py::none(), py::arg("bgr") = false,
          R"doc(Localizes one photo: a path (EXIF focal used when present), or a numpy uint8
array H×W (grey), H×W×3 (RGB; bgr=True for OpenCV's order) or H×W×4 (alpha
ignored), or anything numpy.asarray turns into one (e.g. a PIL image).
intrinsics: None (EXIF, else the focal is estimated), a focal length in
pixels, a dict {focal[, fy][, width, height, cx, cy][, k1]} (focal is fx; fy
defaults to it), or a COLMAP camera
(model, width, height, params). Returns a LocalizationResult; a bad file
raises visloc.Error.)doc")
      .def_property_readonly("num_segments", &Localizer::num_segments)
      .def_property_readonly("has_retrieval", &Localizer::has_retrieval)
      .def_property_readonly("cache_resident_bytes", &Localizer::cache_resident_bytes);
}

// visloc.Segment.
void bind_segment(py::module_& m) {
  py::class_<PySegment, std::shared_ptr<PySegment>>(m, "Segment", "One segment of a map (its file mapped in memory).")
      .def_property_readonly("id", [](const PySegment& s) { return s.segment->id(); })
      .def_property_readonly("num_points", [](const PySegment& s) { return s.segment->num_points(); })
      .def_property_readonly("format_version", [](const PySegment& s) { return s.segment->format_version(); })
      .def_property_readonly("path", [](const PySegment& s) { return s.segment->path().string(); })
      .def_property_readonly(
          "points",
          [](const std::shared_ptr<PySegment>& s) {
            const auto xyz = s->segment->xyz();
            py::array_t<float> a({static_cast<py::ssize_t>(s->segment->num_points()), py::ssize_t(3)},
                                 {py::ssize_t(3 * sizeof(float)), py::ssize_t(sizeof(float))}, xyz.data(),
                                 py::cast(s));
            a.attr("setflags")(py::arg("write") = false);
            return a;
          },
          "Point positions in the segment's frame: a read-only numpy float32 N×3 view of the mapped file (no copy).")
      .def_property_readonly("images", [](const PySegment& s) {
        py::list l;
        for (const auto& im : s.segment->images()) l.append(image_dict(im));
        return l;
      }, "The segment's images: name, camera (COLMAP model id, size, params) and pose (qvec, tvec, world-to-camera).")
      .def_property_readonly("enu_from_segment", [](const PySegment& s) { return similarity_dict(s.segment->enu_from_segment()); },
                             "The similarity {scale, rotation, translation} from the segment's frame to ENU metres, or None.")
      .def_property_readonly("meta", [](const PySegment& s) { return to_python(s.segment->meta()); })
      .def("__repr__", [](const PySegment& s) {
        return "Segment(id=" + std::to_string(s.segment->id()) + ", points=" + std::to_string(s.segment->num_points()) +
               ", images=" + std::to_string(s.segment->images().size()) + ")";
      });
}

// visloc.Map.
void bind_map(py::module_& m) {
  py::class_<PyMap>(m, "Map", "A map directory, opened and checked (manifest, codebook); segments mapped on use.")
      .def(py::init([](const py::object& dir) {
             const fs::path p = path_from(dir, "Map: map_dir");
             return translate_errors([&] { return std::make_unique<PyMap>(p); });
           }),
           py::arg("map_dir"))
      .def("info", [](const PyMap& m) { return translate_errors([&] { return to_python(map_info(m.map().dir()).to_json()); }); },
           "What `visloc map info --json` prints: segments, points, bytes.")
      .def_property_readonly("manifest", [](const PyMap& m) { return to_python(m.map().manifest().to_json()); })
      .def_property_readonly("segments", [](PyMap& m) {
        py::list l;
        translate_errors([&] {
          for (size_t i = 0; i < m.size(); ++i) l.append(m.segment(i));
        });
        return l;
      })
      .def("segment", [](PyMap& m, const py::object& i) { return translate_errors([&] { return m.segment(m.position(i)); }); },
           py::arg("index"), "Segment at this position of the manifest (negative: from the end).")
      .def_property_readonly("num_points", [](const PyMap& m) {
        size_t n = 0;
        for (const auto& s : m.map().manifest().segments) n += s.points;
        return n;
      })
      .def_property_readonly("images", [](PyMap& m) {
        py::list l;
        translate_errors([&] {
          for (size_t i = 0; i < m.size(); ++i) {
            auto s = m.segment(i);
            for (const auto& im : s->segment->images()) {
              py::dict d = image_dict(im);
              d["segment"] = s->segment->id();
              l.append(d);
            }
          }
        });
        return l;
      }, "Every segment's images (a dict each, with its segment id).")
      .def("__len__", &PyMap::size)
      .def("__getitem__", [](PyMap& m, const py::object& i) { return translate_errors([&] { return m.segment(m.position(i)); }); });
}

// visloc.set_opencv_threads.
void bind_opencv_threads(py::module_& m) {
  m.def(
      "set_opencv_threads", [](int threads) { translate_errors([&] { set_opencv_threads(threads); }); },
      py::arg("threads"),
      "Sets OpenCV's thread count, which SIFT uses. It is process-wide (every OpenCV call of the program), "
      "so visloc never changes it by itself: set 1 when several Python threads localize at once.");
}

// visloc.read_image.
void bind_read_image(py::module_& m) {
  m.def(
      "read_image",
      [](const py::object& path, bool with_metadata) -> py::object {
        const fs::path p = path_from(path, "read_image: path");
        if (!fs::exists(p)) raise_error(ErrorCode::kNotFound, p.string() + ": no such file");
        ImageMetadata meta;
        GrayImage g = translate_errors([&] {
          py::gil_scoped_release release;
          return read_gray_image(p, {}, &meta);
        });
        py::array_t<uint8_t> a({static_cast<py::ssize_t>(g.height), static_cast<py::ssize_t>(g.width)});
        std::memcpy(a.mutable_data(), g.pixels.data(), g.pixels.size());
        if (!with_metadata) return a;
        py::dict d;
        d["width"] = meta.width;
        d["height"] = meta.height;
        const auto f = meta.focal_px();
        d["focal_px"] = f ? py::object(py::float_(*f)) : py::none();
        return py::make_tuple(a, d);
      },
      py::arg("path"), py::arg("metadata") = false,
      "The greyscale pixels (numpy uint8 H×W) that localize() decodes from this file; with metadata=True, "
      "(pixels, {width, height, focal_px}).");
}

// visloc.build_map.
void bind_build_map(py::module_& m) {
  m.def(
      "build_map",
      [](const py::object& images, const py::object& out, const py::object& progress, const py::kwargs& kwargs) {
        Kwargs k(kwargs, "build_map");
        MapBuildOptions o;
        o.images_dir = path_from(images, "build_map: images");
        const fs::path map_dir = path_from(out, "build_map: out");
        std::string poses = "sfm", matcher = "auto", hash_rotation;
        const py::object gps = k.take_object("gps");  // None or 'exif': each image's EXIF; else a CSV
        if (!gps.is_none() && !(py::isinstance<py::str>(gps) && gps.cast<std::string>() == "exif")) {
          if (!is_path_like(gps))
            throw py::type_error("build_map: option 'gps' must be 'exif' or the path of a GPS CSV");
          o.gps_csv = path_from(gps, "build_map: gps");
        }
        k.take("gps_subset", o.gps_lists_subset);
        if (k.take_choice("poses", poses, {"sfm", "known"}))
          o.poses = poses == "known" ? PoseSource::kKnown : PoseSource::kSfm;
        k.take("known_poses", o.known_poses);
        k.take("known_intrinsics", o.known_intrinsics);
        if (k.take_choice("matcher", matcher, {"auto", "guided", "colmap", "twoview"}))
          o.matcher = matcher == "guided"    ? PairMatcher::kGuided
                      : matcher == "colmap"  ? PairMatcher::kColmap
                      : matcher == "twoview" ? PairMatcher::kTwoView
                                             : PairMatcher::kDefault;
        k.take("sampson", o.guided.max_sampson_px);
        std::string pair_ransac = "1m-sprt";
        if (k.take_choice("pair_ransac", pair_ransac, {"classic", "1m", "1m-sprt"}))
          o.pair_verification.estimation.variant = pair_ransac == "classic" ? RansacVariant::kClassic11
                                                   : pair_ransac == "1m"    ? RansacVariant::kOneManyFixed
                                                                            : RansacVariant::kOneManySprt;
        k.take("pair_threshold", o.pair_verification.estimation.threshold_px);
        k.take("jobs", o.jobs);
        k.take("colmap", o.colmap.binary);
        k.take("colmap_threads", o.colmap.threads);
        k.take("exhaustive_max", o.exhaustive_max_images);
        k.take("spatial_neighbors", o.colmap.spatial_max_neighbors);
        k.take("min_placemarks", o.plan.min_placemarks);
        k.take("max_placemarks", o.plan.max_placemarks);
        k.take("overlap", o.plan.overlap);
        k.take("placemark_radius", o.plan.placemark_radius);
        bool chain_order = false;
        if (k.take("chain_order", chain_order) && chain_order) o.plan.order = PlacemarkOrder::kChain;
        k.take("registration_threshold", o.registration.inlier_threshold);
        k.take("retrieval", o.build_retrieval);
        if (bool fit = false; k.take("fit_blend", fit)) o.fit_hash_blend = fit;
        k.take("retrieval_dims", o.embedding.output_dims);
        k.take("pq_training_images", o.pq_training_images);
        if (k.take_choice("hash_rotation", hash_rotation, {"segment", "map"}))
          o.hash_rotation = parse_hash_rotation_scope(hash_rotation);
        take_point_coordinates(k, o.segment_file);
        if (int bytes = 0; take_pq_bytes(k, "build_map", bytes)) o.pq_code_bytes = bytes;
        if (PqQuantizer q{}; take_pq_quantizer(k, "build_map", q, o.pq_residual_splits, o.pq_residual_beam))
          o.pq_quantizer = q;
        take_residual_kmeans(k, o.pq);
        take_sift_options(k, o.sift);
        k.finish();
        std::function<void(const MapBuildProgress&)> callback;
        if (!progress.is_none()) {
          if (!PyCallable_Check(progress.ptr())) throw py::type_error("build_map: progress must be callable");
          callback = [progress](const MapBuildProgress& p) {
            py::gil_scoped_acquire acquire;
            py::dict d;
            d["stage"] = p.stage;
            d["done"] = p.done;
            d["total"] = p.total;
            d["elapsed_s"] = p.elapsed_s;
            d["eta_s"] = p.eta_s >= 0 ? py::object(py::float_(p.eta_s)) : py::none();
            py::list running;
            for (const auto& s : p.running) {
              py::dict r;
              r["segment"] = s.segment;
              r["stage"] = s.stage;
              r["done"] = s.done;
              r["total"] = s.total;
              running.append(r);
            }
            d["running"] = running;
            progress(d);  // an exception in the callback propagates and stops the build
          };
        }
        const MapBuildResult r = translate_errors([&] {
          o.validate();
          o.build_record = build_record(o, map_dir).dump(2);
          py::gil_scoped_release release;
          return build_map(map_dir, o, callback);
        });
        if (!r.segments.empty() && r.failed() == r.segments.size())
          raise_error(ErrorCode::kExternalTool,
                      "no segment could be built (see the logs under " + (map_dir / "work").string() + ")");
        nlohmann::json j = to_json(r);
        j["map"] = map_dir.string();
        return to_python(j);
      },
      py::arg("images"), py::arg("out"), py::arg("progress") = py::none(),
      R"doc(Builds a map from geotagged images, as `visloc map build` (resumable).

Keywords as the CLI's flags: gps ('exif' or a CSV), gps_subset, poses ('sfm' or
'known'), known_poses, known_intrinsics, matcher ('auto', 'guided', 'colmap',
'twoview'), sampson, pair_ransac ('classic', '1m', '1m-sprt'), pair_threshold, jobs, colmap, colmap_threads, exhaustive_max, spatial_neighbors,
min_placemarks, max_placemarks, overlap, placemark_radius, chain_order,
registration_threshold, retrieval, retrieval_dims, pq_training_images,
hash_rotation, point_coordinates ('auto', 'float32', 'int16'), point_uncertainty
(bool, default False), pq_bytes (16 or
32; default: an existing map's, 16 for a new one), pq_quantizer ('product' or
'residual': 16-byte codes of 16 codebooks added, a finer ranking at a slower
search, seconds of training; default: an existing map's, 'product' for a
new one), pq_residual_splits (1, 2 or 4) and pq_residual_beam (1 to 64) of
residual codes (default: an existing map's, 2 and 1 for a new one),
pq_residual_kmeans ('plain', the default, or 'progressive': their training), fit_blend (None,
the default: fit the hash-blend weight last and warn in the report's hash_blend_error when it
cannot; True: fail then; False: no fit) and the SIFT options. MAP/work is kept (a resumed build,
map update and fit_blend read it). progress(dict) is called as the
build advances. Local executor only (Slurm builds: the CLI). Segments are
built `jobs` at a time (default: one per core), each SIFT on OpenCV's
process-wide pool: call visloc.set_opencv_threads(1) first, as the CLI does,
so that they do not compete. Returns the build's statistics as a dict.)doc");
}

// visloc.import_colmap.
void bind_import_colmap(py::module_& m) {
  m.def(
      "import_colmap",
      [](const py::object& model, const py::object& database, const py::object& out, const py::kwargs& kwargs) {
        Kwargs k(kwargs, "import_colmap");
        ColmapImportOptions o;
        const fs::path model_dir = path_from(model, "import_colmap: model"),
                       db = path_from(database, "import_colmap: database"), map_dir = path_from(out, "import_colmap: out");
        o.holdout_images = names_from(k.take_object("holdout"), "import_colmap: holdout");
        k.take("pq_train_database", o.pq_training_database);
        o.pq_training_images = names_from(k.take_object("pq_train_images"), "import_colmap: pq_train_images");
        std::string hash_rotation;
        if (k.take_choice("hash_rotation", hash_rotation, {"segment", "map"}))
          o.hash_rotation = parse_hash_rotation_scope(hash_rotation);
        take_point_coordinates(k, o.segment_file);
        take_pq_bytes(k, "import_colmap", o.pq.subvectors);
        std::optional<int> residual_splits, residual_beam;
        take_pq_quantizer(k, "import_colmap", o.pq.quantizer, residual_splits, residual_beam);
        o.pq.residual_splits = residual_splits.value_or(o.pq.residual_splits);
        o.pq.residual_beam = residual_beam.value_or(o.pq.residual_beam);
        take_residual_kmeans(k, o.pq);
        k.take("itq_iterations", o.itq.iterations);
        k.take("seed", o.itq.seed);
        k.take("keep_descriptors", o.keep_descriptors);
        k.take("overwrite", o.overwrite);
        if (bool fit = false; k.take("fit_blend", fit)) o.fit_hash_blend = fit;
        k.finish();
        o.pq.seed = o.itq.seed;
        const ColmapImportResult r = translate_errors([&] {
          o.validate();
          py::gil_scoped_release release;
          return import_colmap_map(model_dir, db, map_dir, o);
        });
        nlohmann::json j = to_json(r);
        j["map"] = map_dir.string();
        return to_python(j);
      },
      py::arg("model"), py::arg("database"), py::arg("out"),
      R"doc(Imports a COLMAP model and its database as a one-segment map, as
`visloc map import --colmap`. Keywords: holdout (names or a file of names:
removed from the model, kept as queries), pq_train_database,
pq_train_images, hash_rotation ('segment' or 'map'), point_coordinates ('auto',
'float32', 'int16'), point_uncertainty (bool, default False), pq_bytes (16 or 32),
pq_quantizer ('product' or 'residual'),
pq_residual_splits (1, 2 or 4; default 2), pq_residual_beam (1 to 64; default 1),
pq_residual_kmeans ('plain', the default, or 'progressive'),
itq_iterations, seed, keep_descriptors, overwrite, fit_blend (None, the default:
fit the hash-blend weight on the new map and store it, and warn in the result's
hash_blend_error when it cannot; True: fail then, as --fit-blend; False: no fit,
as --no-fit-blend).
Returns the import statistics as a dict.)doc");
}

// visloc.fit_blend.
void bind_fit_blend(py::module_& m) {
  m.def(
      "fit_blend",
      [](const py::object& map, const py::kwargs& kwargs) {
        Kwargs k(kwargs, "fit_blend");
        const fs::path map_dir = path_from(map, "fit_blend: map_dir");
        MapBlendFitOptions o;
        bool store = false;
        k.take("views", o.views);
        k.take("weight_steps", o.fit.weight_steps);
        k.take("store", store);
        k.finish();
        nlohmann::json j = translate_errors([&] {
          o.validate();
          py::gil_scoped_release release;
          const MapBlendFit fit = fit_map_hash_blend(map_dir, o);
          if (store) store_map_hash_blend(map_dir, fit);
          return fit.to_json();
        });
        j["stored"] = store;
        return to_python(j);
      },
      py::arg("map_dir"),
      R"doc(Fits the cascade search's hash-blend weight on the map's own data, as
`visloc map fit-blend --json`. Keywords: views (points sampled, default 4000),
weight_steps (default 20), store (bool, default False: write the weight into
the map's manifest, where Localizer takes it by default; refused while a build
of the map is running). Returns the fit as a
dict: weight, views, distractors, grid, segments, stored.)doc");
}

// visloc.evaluate.
void bind_evaluate(py::module_& m) {
  m.def(
      "evaluate",
      [](const py::object& map_dir, const py::object& out, const py::kwargs& kwargs) {
        Kwargs k(kwargs, "evaluate");
        EvaluationRunOptions o;
        o.map = path_from(map_dir, "evaluate: map");
        o.out = path_from(out, "evaluate: out");
        const py::object queries = k.take_object("queries");
        o.queries = names_from(queries, "evaluate: queries");
        if (!queries.is_none() && o.queries.empty())
          raise_error(ErrorCode::kInvalidArgument, "evaluate: queries: no query names");
        k.take("images", o.images_dir);
        k.take("truth", o.truth);
        const py::object intrinsics = k.take_object("intrinsics");
        std::string query_features = "images", compare;
        if (k.take_choice("query_features", query_features, {"images", "database"}))
          o.query_features = parse_query_feature_source(query_features);
        k.take("leave_one_out", o.leave_one_out);
        const py::object negatives = k.take_object("negatives");
        if (k.take_choice("compare", compare, {"colmap"})) o.compare_colmap = true;
        k.take("colmap", o.colmap.binary);
        take_localizer_options(k, o.localizer);
        k.finish();
        if (!intrinsics.is_none()) {
          if (py::isinstance<py::dict>(intrinsics)) {
            for (auto item : intrinsics.cast<py::dict>()) {
              auto cam = intrinsics_from_python(py::reinterpret_borrow<py::object>(item.second));
              if (cam) o.intrinsics[py::str(item.first).cast<std::string>()] = *cam;
            }
          } else {
            const fs::path p = path_from(intrinsics, "evaluate: intrinsics");
            translate_errors([&] { o.intrinsics = read_intrinsics_by_name(p); });
          }
        }
        if (!negatives.is_none()) {
          if (is_path_like(negatives))
            o.negatives_source = path_from(negatives, "evaluate: negatives").string();
          o.negatives = names_from(negatives, "evaluate: negatives");
          if (o.negatives.empty()) raise_error(ErrorCode::kInvalidArgument, "evaluate: negatives: no image paths");
        }
        const EvaluationRunResult r = translate_errors([&] {
          o.validate();
          py::gil_scoped_release release;
          return run_evaluation(o);
        });
        py::object report = to_python(r.report);
        if (r.colmap_report) {
          report["colmap"] = to_python(*r.colmap_report);
          report["comparison_markdown"] = r.comparison_markdown;
        }
        return report;
      },
      py::arg("map"), py::arg("out"),
      R"doc(Localizes a query list against a map and writes the report folder, as
`visloc eval`. Keywords: queries (names or a file), images (their folder),
truth (pose list, COLMAP images.txt or model, or GPS CSV), intrinsics (a file
'name MODEL w h params...' or a dict name -> intrinsics), query_features
('images' or 'database'), leave_one_out, negatives (paths or a file),
compare='colmap', colmap (the executable), and the Localizer options.
Returns report.json as a dict (with compare: 'colmap' and
'comparison_markdown' too).)doc");
}

}  // namespace

// Each type is bound before the first signature that names it (pybind11 writes
// the Python names into the docstrings as it binds).
void bind(py::module_& m) {
  bind_errors(m);
  bind_pose(m);
  bind_localization_result(m);
  bind_localizer(m);
  bind_segment(m);
  bind_map(m);
  bind_opencv_threads(m);
  bind_read_image(m);
  bind_build_map(m);
  bind_import_colmap(m);
  bind_fit_blend(m);
  bind_evaluate(m);
}

}  // namespace visloc::python

PYBIND11_MODULE(_core, m) {
  m.doc() = "visloc: visual localization against city-scale street-view maps (C++ core)";
  visloc::python::bind(m);
}
