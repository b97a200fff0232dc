"""Tests of the Python bindings (`import visloc`), run by ctest as python.pytest.

Environment (set by CMake): PYTHONPATH (build/python), VISLOC_CLI (the CLI
binary), VISLOC_SHARED_DATA_DIR, VISLOC_TEST_FOUNTAIN_MAP (the fountain-P11
map the C API fixture imports). Tests that need COLMAP or the shared data
skip with a message when they are absent.
"""

import concurrent.futures
import json
import math
import os
import pathlib
import shutil
import subprocess

import numpy as np
import pytest

import visloc

CLI = os.environ.get("VISLOC_CLI", "visloc")
DATA = pathlib.Path(os.environ.get("VISLOC_SHARED_DATA_DIR", "../shared/data"))
FOUNTAIN = DATA / "strecha" / "fountain-P11"
FOUNTAIN_MAP = pathlib.Path(os.environ.get("VISLOC_TEST_FOUNTAIN_MAP", "build/src/visloc/capi/fountain_map"))


# --- Without data ---------------------------------------------------------------


def test_public_api():
    for name in ["Localizer", "Map", "build_map", "import_colmap", "fit_blend", "evaluate", "read_image", "Error"]:
        assert hasattr(visloc, name), name
    assert issubclass(visloc.InvalidArgumentError, visloc.Error)
    assert issubclass(visloc.InvalidArgumentError, ValueError)
    assert issubclass(visloc.NotFoundError, FileNotFoundError)
    assert issubclass(visloc.FormatError, ValueError)


def test_set_opencv_threads():
    visloc.set_opencv_threads(1)
    with pytest.raises(ValueError, match="threads"):
        visloc.set_opencv_threads(0)


def test_missing_map_raises(tmp_path):
    with pytest.raises(visloc.Error) as e:
        visloc.Localizer(tmp_path / "nothing")
    assert "nothing" in str(e.value)
    with pytest.raises(visloc.Error):
        visloc.Map(str(tmp_path / "nothing"))


def test_not_a_map_raises_format_error(tmp_path):
    (tmp_path / "manifest.json").write_text("{ not json")
    with pytest.raises(visloc.FormatError) as e:
        visloc.Map(tmp_path)
    assert "manifest.json" in str(e.value)


@pytest.mark.parametrize(
    "options, error, field",
    [
        ({"top_images": 0}, ValueError, "top_images"),
        ({"max_segments": -1}, ValueError, "max_segments"),
        ({"fallback_segments": -1}, ValueError, "fallback_segments"),
        ({"min_confidence": 1.5}, ValueError, "min_confidence"),
        ({"min_confidence": float("nan")}, ValueError, "min_confidence"),
        ({"threshold_px": float("inf")}, ValueError, "threshold_px"),
        ({"cache_mib": 0.5}, ValueError, "cache_mib"),
        ({"min_inliers": -3}, ValueError, "min_inliers"),
        ({"setting": "4"}, ValueError, "setting"),
        ({"segment_votes": "pixels"}, ValueError, "segment_votes"),
        ({"vote_points": -1}, ValueError, "vote_points"),
        ({"vote_max_points": -1}, ValueError, "vote_max_points"),
        ({"max_drop_below_map": -1.0}, ValueError, "max_drop"),
        ({"under_street_check": 1}, TypeError, "under_street_check"),
        ({"map_point_uncertainty": "no"}, TypeError, "map_point_uncertainty"),
        ({"vote_radius": 2}, ValueError, "vote_radius"),
        ({"lut_flips": 17}, ValueError, "lut_flips"),
        ({"lut_flips_min_list": -1}, ValueError, "lut_flips_min_list"),
        ({"hash_blend": 1.5}, ValueError, "hash_blend"),
        ({"hash_blend": float("nan")}, ValueError, "hash_blend"),
        ({"hash_blend": "mpa"}, ValueError, "hash_blend"),
        ({"hash_blend": True}, TypeError, "hash_blend"),
        ({"hash_blend": [0.5]}, TypeError, "hash_blend"),
        ({"hash_blend": np.float32(1.5)}, ValueError, "hash_blend"),
        ({"vote_ratio": 1.5}, ValueError, "vote_ratio"),
        ({"vote_ratio": 0.0}, ValueError, "vote_ratio"),
        ({"top_images": "20"}, TypeError, "top_images"),
        ({"use_exif_focal": 1}, TypeError, "use_exif_focal"),
        ({"top_image": 20}, TypeError, "top_image"),
        ({"top_images": 2**32 + 5}, ValueError, "top_images"),
        ({"accept_inliers": 2**32}, ValueError, "accept_inliers"),
        ({"seed": -1}, ValueError, "seed"),
        ({"cache_mib": 1e300}, ValueError, "cache_mib"),
        ({"top_images": np.bool_(True)}, TypeError, "top_images"),
        ({"setting": b"3"}, TypeError, "setting"),
    ],
)
def test_bad_options_name_the_field(tmp_path, options, error, field):
    # Options are checked before the map is opened: no map is needed.
    with pytest.raises(error) as e:
        visloc.Localizer(tmp_path / "no-map", **options)
    assert field in str(e.value)


def test_bad_build_and_import_options(tmp_path):
    with pytest.raises(TypeError, match="placemarks"):
        visloc.build_map(tmp_path, tmp_path / "map", placemarks=3)
    with pytest.raises(ValueError, match="poses"):
        visloc.build_map(tmp_path, tmp_path / "map", poses="guess")
    with pytest.raises(TypeError, match="progress"):
        visloc.build_map(tmp_path, tmp_path / "map", progress=3)
    with pytest.raises(TypeError, match="holdot"):
        visloc.import_colmap(tmp_path, tmp_path / "db", tmp_path / "map", holdot=["a"])
    with pytest.raises(visloc.Error):
        visloc.import_colmap(tmp_path / "model", tmp_path / "database.db", tmp_path / "map")
    with pytest.raises(ValueError, match="build_map: pq_bytes must be 16 or 32, got 24"):
        visloc.build_map(tmp_path, tmp_path / "map", pq_bytes=24)
    with pytest.raises(ValueError, match="import_colmap: pq_bytes must be 16 or 32, got 8"):
        visloc.import_colmap(tmp_path, tmp_path / "db", tmp_path / "map", pq_bytes=8)
    with pytest.raises(ValueError, match="build_map: pq_quantizer must be one of 'product', 'residual', got 'opq'"):
        visloc.build_map(tmp_path, tmp_path / "map", pq_quantizer="opq")
    with pytest.raises(ValueError, match="import_colmap: pq_residual_splits must be 1, 2 or 4, got 3"):
        visloc.import_colmap(tmp_path, tmp_path / "db", tmp_path / "map", pq_quantizer="residual",
                             pq_residual_splits=3)
    with pytest.raises(ValueError, match="build_map: pq_residual_beam must be in \\[1, 64\\], got 0"):
        visloc.build_map(tmp_path, tmp_path / "map", pq_quantizer="residual", pq_residual_beam=0)
    with pytest.raises(ValueError, match="import_colmap: pq_residual_kmeans must be one of 'progressive', 'plain'"):
        visloc.import_colmap(tmp_path, tmp_path / "db", tmp_path / "map", pq_residual_kmeans="fast")
    # Residual codes are 16 bytes: refused before the (missing) model is read.
    with pytest.raises(ValueError, match="residual codebook has 16-byte codes, not 32"):
        visloc.import_colmap(tmp_path, tmp_path / "db", tmp_path / "map", pq_quantizer="residual", pq_bytes=32)
    with pytest.raises(TypeError, match="point_uncertainty"):
        visloc.import_colmap(tmp_path, tmp_path / "db", tmp_path / "map", point_uncertainty=1)
    with pytest.raises(TypeError, match="point_uncertainty"):
        visloc.build_map(tmp_path, tmp_path / "map", point_uncertainty="yes")
    with pytest.raises(TypeError, match="fit_blend"):
        visloc.import_colmap(tmp_path, tmp_path / "db", tmp_path / "map", fit_blend=1)
    with pytest.raises(ValueError, match="--fit-blend"):  # it needs the descriptors
        visloc.import_colmap(tmp_path, tmp_path / "db", tmp_path / "map", fit_blend=True, keep_descriptors=False)
    with pytest.raises(TypeError, match="fit_blend"):
        visloc.build_map(tmp_path, tmp_path / "map", fit_blend="yes")
    with pytest.raises(ValueError, match="queries and truth"):
        visloc.evaluate(tmp_path, tmp_path / "out", images=tmp_path)


def test_read_image_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        visloc.read_image(tmp_path / "none.jpg")
    (tmp_path / "bad.jpg").write_bytes(b"not a jpeg at all")
    with pytest.raises(visloc.Error) as e:
        visloc.read_image(tmp_path / "bad.jpg")
    assert "bad.jpg" in str(e.value)


# --- A small synthetic street: build, open, localize, evaluate -----------------


@pytest.fixture(scope="module")
def street(tmp_path_factory):
    if shutil.which("colmap") is None:
        pytest.skip("colmap is not installed (map building triangulates with it)")
    root = tmp_path_factory.mktemp("street")
    city = root / "city"
    subprocess.run(
        [CLI, "synth", "city", "--out", str(city), "--road-length", "60", "--headings", "6", "--elevations", "10",
         "--queries", "6", "--jobs", "1"],
        check=True, stdout=subprocess.DEVNULL)
    progress = []
    report = visloc.build_map(
        city / "images", root / "map", gps=str(city / "gps.csv"), poses="known", known_poses=city / "sparse",
        jobs=1, min_placemarks=3, max_placemarks=3, overlap=1, retrieval=False, pq_training_images=6,
        progress=lambda p: progress.append(p))
    return {"city": city, "map": root / "map", "report": report, "progress": progress, "root": root}


def test_build_map_reports_and_progresses(street):
    report = street["report"]
    assert report["failed"] == 0
    assert len(report["segments"]) >= 2
    assert all(s["ok"] and s["points"] > 0 for s in report["segments"])
    stages = {p["stage"] for p in street["progress"]}
    assert "segments" in stages, stages
    # The CLI reads the same map.
    info = json.loads(subprocess.run([CLI, "map", "info", str(street["map"]), "--json"], check=True,
                                     capture_output=True, text=True).stdout)
    assert info["total"]["points"] == sum(s["points"] for s in report["segments"])


def test_python_build_records_its_options_for_the_cli(street):
    # `map build-segment` (what a Slurm task runs) rebuilds a segment of a map
    # started from Python with the options recorded in MAP/work/build.json.
    record = json.loads((street["map"] / "work" / "build.json").read_text())
    assert "--known-poses" in record["args"] and "--no-retrieval" in record["args"]
    # The map's codes are the PQ's: asking for residual codes on it is refused
    # before anything is written, and the build record stays the first one's.
    with pytest.raises(ValueError, match="PQ codes are of the product quantizer"):
        visloc.build_map(street["city"] / "images", street["map"], gps=str(street["city"] / "gps.csv"),
                         poses="known", known_poses=street["city"] / "sparse", pq_quantizer="residual",
                         pq_residual_splits=4)
    assert json.loads((street["map"] / "work" / "build.json").read_text()) == record
    done = subprocess.run([CLI, "map", "build-segment", str(street["map"]), "0"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("segment 0:"), done.stdout


def test_map_exposes_segments_points_images(street):
    m = visloc.Map(street["map"])
    assert m[-1].id == m.segments[-1].id
    with pytest.raises(IndexError):
        m[len(m)]
    with pytest.raises(TypeError):
        m[True]
    info = m.info()
    assert len(m) == len(info["segments"]) == len(m.segments)
    total = 0
    for seg in m.segments:
        pts = seg.points
        assert pts.shape == (seg.num_points, 3) and pts.dtype == np.float32
        assert not pts.flags.writeable
        assert not pts.flags.owndata  # a view of the mapped file, not a copy
        assert np.isfinite(pts).all()
        assert seg.enu_from_segment is not None and seg.enu_from_segment["scale"] > 0
        assert all(len(im["qvec"]) == 4 for im in seg.images)
        total += seg.num_points
    assert total == info["total"]["points"] == m.num_points
    assert {im["segment"] for im in m.images} == {s.id for s in m.segments}
    # The view keeps its segment (and the mapping) alive.
    pts = visloc.Map(street["map"]).segments[0].points
    assert np.isfinite(pts.sum())


def read_intrinsics(path):
    cams = {}
    for line in pathlib.Path(path).read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        name, model, w, h, *params = line.split()
        cams[name] = (model, int(w), int(h), [float(p) for p in params])
    return cams


def test_localize_and_evaluate_street(street, tmp_path):
    city = street["city"]
    names = (city / "queries" / "list.txt").read_text().split()
    cams = read_intrinsics(city / "queries" / "intrinsics.txt")
    loc = visloc.Localizer(street["map"])
    results = [loc.localize(city / "queries" / "images" / n, intrinsics=cams[n]) for n in names]
    for r in results:
        assert 0.0 <= r.confidence <= 1.0
        if r.registered:
            assert r.pose is not None and r.center_enu is not None
            assert r.lat is not None and -90 <= r.lat <= 90
            assert r.pose.cam_from_world.shape == (3, 4)
    report = visloc.evaluate(street["map"], tmp_path / "eval", queries=names, images=city / "queries" / "images",
                             truth=city / "queries" / "truth.txt", intrinsics=city / "queries" / "intrinsics.txt")
    assert report["queries"] == len(names)
    assert report["registered"] == sum(r.registered for r in results)
    assert (tmp_path / "eval" / "report.md").exists()


def test_build_map_with_residual_codes(street, tmp_path):
    # The same street with residual PQ codes (trained on one image's
    # descriptors, to keep it quick): the map says so, and localizes as the
    # product-coded one does.
    city = street["city"]
    visloc.build_map(city / "images", tmp_path / "map", gps=str(city / "gps.csv"), poses="known",
                     known_poses=city / "sparse", jobs=1, min_placemarks=3, max_placemarks=3, overlap=1,
                     retrieval=False, pq_training_images=1, pq_quantizer="residual", pq_residual_splits=4,
                     pq_residual_beam=2)
    total = visloc.Map(tmp_path / "map").info()["total"]
    assert (total["pq_quantizer"], total["pq_residual_splits"], total["pq_residual_beam"],
            total["pq_code_bytes"]) == ("residual", 4, 2, 16)
    product = visloc.Map(street["map"]).info()["total"]
    assert (product["pq_quantizer"], product["pq_residual_splits"], product["pq_residual_beam"]) == \
        ("product", None, None)
    record = json.loads((tmp_path / "map" / "work" / "build.json").read_text())["args"]
    assert record[record.index("--pq-quantizer") + 1] == "residual"
    assert record[record.index("--pq-residual-splits") + 1] == "4"
    assert record[record.index("--pq-residual-beam") + 1] == "2"
    assert record[record.index("--pq-residual-kmeans") + 1] == "plain"  # the default
    # Resumed with another beam: refused, naming the map's.
    with pytest.raises(ValueError, match="--pq-residual-beam 2"):
        visloc.build_map(city / "images", tmp_path / "map", gps=str(city / "gps.csv"), poses="known",
                         known_poses=city / "sparse", pq_residual_beam=3)
    names = (city / "queries" / "list.txt").read_text().split()
    cams = read_intrinsics(city / "queries" / "intrinsics.txt")
    registered = {}
    for m in (street["map"], tmp_path / "map"):
        loc = visloc.Localizer(m)
        registered[m] = sum(loc.localize(city / "queries" / "images" / n, intrinsics=cams[n]).registered
                            for n in names)
    assert registered[tmp_path / "map"] >= registered[street["map"]] - 1, registered


# --- fountain-P11 (shared data): the CLI's poses, numpy frames, threads ---------


@pytest.fixture(scope="module")
def fountain():
    if not (FOUNTAIN / "images").is_dir():
        pytest.skip(f"shared data absent: {FOUNTAIN}")
    if not (FOUNTAIN_MAP / "manifest.json").exists():
        pytest.skip(f"no map at {FOUNTAIN_MAP} (the ctest fixture capi.import_fountain_map imports it)")
    queries = (FOUNTAIN / "queries.txt").read_text().split()
    return {"queries": queries, "images": [FOUNTAIN / "images" / q for q in queries]}


def fountain_camera():
    for line in (FOUNTAIN / "colmap" / "sparse" / "cameras.txt").read_text().splitlines():
        if line and not line.startswith("#"):
            _, model, w, h, *params = line.split()
            return (model, int(w), int(h), [float(p) for p in params])
    raise AssertionError("no camera in cameras.txt")


def test_holdout_matches_cli(fountain):
    """The Python poses are the CLI's (same options, same images)."""
    out = subprocess.run([CLI, "localize", "--map", str(FOUNTAIN_MAP), "--max-features", "16384",
                          *map(str, fountain["images"])], check=True, capture_output=True, text=True).stdout
    cli = [json.loads(line) for line in out.splitlines()]
    loc = visloc.Localizer(FOUNTAIN_MAP, max_features=16384)
    registered = 0
    for path, expected in zip(fountain["images"], cli):
        r = loc.localize(path)
        d = r.to_dict()
        assert d["image"] == expected["image"] == path.name
        assert r.registered == expected["registered"]
        assert r.inliers == expected["inliers"]
        if r.registered:
            registered += 1
            center = r.pose.center
            # The CLI's JSON line carries the pose as q_wxyz and t (world-to-camera).
            q = np.array(expected["q_wxyz"])
            t = np.array(expected["t"])
            assert np.abs(r.pose.tvec - t).max() <= 1e-9
            assert min(np.abs(r.pose.qvec - q).max(), np.abs(r.pose.qvec + q).max()) <= 1e-12
            assert np.isfinite(center).all()
    assert registered == len(fountain["images"])


def test_numpy_frame_equals_file(fountain):
    cam = fountain_camera()
    loc = visloc.Localizer(FOUNTAIN_MAP, max_features=16384)
    path = fountain["images"][0]
    from_file = loc.localize(path, intrinsics=cam)
    pixels = visloc.read_image(path)
    assert pixels.dtype == np.uint8 and pixels.shape == (cam[2], cam[1])
    from_array = loc.localize(pixels, intrinsics=cam)
    assert from_file.registered and from_array.registered
    assert from_array.inliers == from_file.inliers
    assert np.array_equal(from_array.pose.qvec, from_file.pose.qvec)
    assert np.array_equal(from_array.pose.tvec, from_file.pose.tvec)
    # Three equal channels are the same grey image.
    rgb = np.repeat(pixels[:, :, None], 3, axis=2)
    from_rgb = loc.localize(rgb, intrinsics=cam)
    assert np.array_equal(from_rgb.pose.tvec, from_file.pose.tvec)
    # RGBA: the alpha channel is ignored.
    rgba = np.concatenate([rgb, np.full(pixels.shape + (1,), 7, dtype=np.uint8)], axis=2)
    assert np.array_equal(loc.localize(rgba, intrinsics=cam).pose.tvec, from_file.pose.tvec)
    # A non-contiguous view is accepted (copied).
    from_view = loc.localize(np.asfortranarray(pixels), intrinsics=cam)
    assert np.array_equal(from_view.pose.tvec, from_file.pose.tvec)


def test_bad_frames_and_intrinsics(fountain):
    loc = visloc.Localizer(FOUNTAIN_MAP)
    with pytest.raises(ValueError, match="uint8"):
        loc.localize(np.zeros((64, 64), dtype=np.float32))
    with pytest.raises(ValueError, match="H×W"):
        loc.localize(np.zeros((4, 64, 64), dtype=np.uint8))
    with pytest.raises(ValueError, match="channels"):
        loc.localize(np.zeros((64, 64, 5), dtype=np.uint8))
    with pytest.raises(TypeError):
        loc.localize(12)
    with pytest.raises(ValueError, match="focal"):
        loc.localize(fountain["images"][0], intrinsics=-5.0)
    with pytest.raises(ValueError, match="focal"):
        loc.localize(fountain["images"][0], intrinsics=float("nan"))
    with pytest.raises(ValueError, match="unknown key"):
        loc.localize(fountain["images"][0], intrinsics={"focal": 2000, "fx": 1})
    with pytest.raises(ValueError, match="intrinsics"):
        loc.localize(fountain["images"][0], intrinsics=("PINHOLE", 10, 10, [1, 1, 5, 5]))
    with pytest.raises(visloc.NotFoundError):
        loc.localize(FOUNTAIN / "images" / "missing.jpg")
    r = loc.localize(np.zeros((64, 64), dtype=np.uint8))  # no features: not registered, no exception
    assert not r.registered and r.pose is None


def test_numpy_scalars_are_numbers(fountain):
    loc = visloc.Localizer(FOUNTAIN_MAP, top_images=np.int64(20), min_confidence=np.float32(0.5),
                           max_features=np.int32(16384))
    model, w, h, params = fountain_camera()
    r = loc.localize(fountain["images"][0], intrinsics={"focal": np.float64(params[0]), "width": np.int64(w),
                                                        "height": h, "cx": params[2], "cy": params[3]})
    assert r.registered


def test_intrinsics_dict_with_fy_is_the_pinhole_camera(fountain):
    """fountain-P11's PINHOLE camera has fx != fy: a dict with fy gives the
    COLMAP camera's pose, and the same dict without fy (square pixels) does not."""
    loc = visloc.Localizer(FOUNTAIN_MAP)
    model, w, h, (fx, fy, cx, cy) = fountain_camera()
    assert model == "PINHOLE" and fx != fy
    image = fountain["images"][0]
    colmap = loc.localize(image, intrinsics=(model, w, h, [fx, fy, cx, cy]))
    with_fy = loc.localize(image, intrinsics={"focal": fx, "fy": fy, "width": w, "height": h, "cx": cx, "cy": cy})
    square = loc.localize(image, intrinsics={"focal": fx, "width": w, "height": h, "cx": cx, "cy": cy})
    assert colmap.registered and with_fy.registered and square.registered
    assert np.array_equal(colmap.pose.tvec, with_fy.pose.tvec)
    assert not np.array_equal(colmap.pose.tvec, square.pose.tvec)
    with pytest.raises(ValueError, match="fy"):
        loc.localize(image, intrinsics={"focal": fx, "fy": 3 * fx})


def test_two_threads_give_the_same_results(fountain):
    loc = visloc.Localizer(FOUNTAIN_MAP, max_features=16384)
    cam = fountain_camera()
    work = fountain["images"] * 2
    alone = [loc.localize(p, intrinsics=cam) for p in work]
    with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:
        together = list(pool.map(lambda p: loc.localize(p, intrinsics=cam), work))
    for a, b in zip(alone, together):
        assert a.registered == b.registered and a.inliers == b.inliers
        assert np.array_equal(a.pose.tvec, b.pose.tvec)


def test_result_fields(fountain):
    loc = visloc.Localizer(FOUNTAIN_MAP, max_features=16384)
    r = loc.localize(fountain["images"][0], intrinsics=fountain_camera())
    d = r.to_dict()
    assert d["registered"] is True and d["inliers"] == r.inliers
    assert set(r.times_ms) == {"features", "retrieval", "matching", "ransac", "total"}
    assert r.times_ms["total"] >= r.times_ms["features"] > 0
    R = r.pose.cam_from_world[:, :3]
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert math.isclose(np.linalg.norm(r.pose.qvec), 1.0, rel_tol=1e-12)
    assert np.allclose(r.pose.center, -R.T @ r.pose.tvec, atol=1e-9)
    assert "registered=True" in repr(r)


def test_import_colmap_and_evaluate(fountain, tmp_path):
    stats = visloc.import_colmap(FOUNTAIN / "colmap" / "sparse", FOUNTAIN / "colmap" / "database.db",
                                 tmp_path / "map", holdout=FOUNTAIN / "queries.txt", itq_iterations=10,
                                 keep_descriptors=False)
    assert stats["holdout"]["images_removed"] == len(fountain["queries"])
    # Without descriptors the default does not fit the hash blend, and says nothing.
    assert stats["hash_blend_weight"] is None and stats["hash_blend_error"] == ""
    assert stats["points"] > 1000
    assert visloc.Map(tmp_path / "map").info()["total"]["pq_code_bytes"] == 16
    stats32 = visloc.import_colmap(FOUNTAIN / "colmap" / "sparse", FOUNTAIN / "colmap" / "database.db",
                                   tmp_path / "map32", holdout=FOUNTAIN / "queries.txt", itq_iterations=3, pq_bytes=32,
                                   fit_blend=True)
    info32 = visloc.Map(tmp_path / "map32").info()
    # fit_blend: the hash-blend weight fitted on the new map, stored for its segment, the localizer's default.
    assert 0 <= stats32["hash_blend_weight"] <= 1
    assert info32["hash_blend"] == {"weight": stats32["hash_blend_weight"], "current": True}
    assert info32["total"]["pq_code_bytes"] == 32
    fit = visloc.fit_blend(tmp_path / "map32", views=500, weight_steps=4)
    assert fit["stored"] is False and len(fit["grid"]) == 5 and fit["views"] == 500
    assert visloc.Map(tmp_path / "map32").info()["hash_blend"]["weight"] == stats32["hash_blend_weight"]
    stored = visloc.fit_blend(tmp_path / "map32", views=500, weight_steps=4, store=True)
    assert visloc.Map(tmp_path / "map32").info()["hash_blend"] == {"weight": stored["weight"], "current": True}
    # The manifest holds this fit, not the import's (4000 views, 20 steps).
    kept = visloc.Map(tmp_path / "map32").manifest["hash_blend"]["fit"]
    assert kept["weight_steps"] == 4 and kept["views"] == 500, kept
    visloc.Localizer(tmp_path / "map32", hash_blend=np.float32(0.25))  # a numpy scalar is a number: no error
    with pytest.raises(ValueError, match="views"):
        visloc.fit_blend(tmp_path / "map32", views=1)
    with pytest.raises(TypeError, match="store"):
        visloc.fit_blend(tmp_path / "map32", store="yes")
    with pytest.raises(visloc.Error, match="kept no point descriptors"):
        visloc.fit_blend(tmp_path / "map")
    assert info32["segments"][0]["format_version"] == 4
    with pytest.raises(visloc.Error, match="overwrite|exists|not empty"):
        visloc.import_colmap(FOUNTAIN / "colmap" / "sparse", FOUNTAIN / "colmap" / "database.db",
                             tmp_path / "map", holdout=fountain["queries"])
    report = visloc.evaluate(tmp_path / "map", tmp_path / "eval", queries=fountain["queries"],
                             images=FOUNTAIN / "images", truth=FOUNTAIN / "truth.txt", max_features=16384)
    assert report["queries"] == len(fountain["queries"])
    assert report["registered"] == len(fountain["queries"])
    assert report["position_error_m"]["median"] < 0.5
