"""The geometry of bench/strecha_cross_scene.py: the similarity fit, the
quaternion conversions and the reference pose it writes in the map's frame."""
import importlib.util
import sys
from pathlib import Path

import numpy as np

spec = importlib.util.spec_from_file_location("strecha_cross_scene", Path(__file__).with_name("strecha_cross_scene.py"))
xs = importlib.util.module_from_spec(spec)
sys.modules["strecha_cross_scene"] = xs
spec.loader.exec_module(xs)


def random_rotation(rng):
    q = rng.normal(size=4)
    return xs.quat_to_rot(q / np.linalg.norm(q))


def test_quaternion_round_trip_and_rotation():
    rng = np.random.default_rng(3)
    for _ in range(200):
        R = random_rotation(rng)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1)
        assert np.allclose(xs.quat_to_rot(xs.rot_to_quat(R)), R, atol=1e-9)
    assert np.allclose(xs.quat_to_rot(np.array([np.cos(0.5), 0, 0, np.sin(0.5)])),
                       [[np.cos(1), -np.sin(1), 0], [np.sin(1), np.cos(1), 0], [0, 0, 1]])  # 1 rad about z


def test_umeyama_recovers_a_similarity():
    rng = np.random.default_rng(4)
    src = rng.normal(size=(12, 3)) * 5
    R, s, t = random_rotation(rng), 3.7, np.array([1.0, -20.0, 4.0])
    s_fit, R_fit, t_fit = xs.umeyama(src, s * (R @ src.T).T + t)
    assert np.isclose(s_fit, s) and np.allclose(R_fit, R) and np.allclose(t_fit, t)


def test_reference_pose_in_the_map_frame_projects_like_the_joint_pose():
    # A camera posed in the joint frame, and the map's frame = a similarity of
    # the joint one: the reference pose written for the map's frame must see a
    # point where the joint pose sees it, at the map frame's scale.
    rng = np.random.default_rng(5)
    R_q, t_q = random_rotation(rng), rng.normal(size=3)
    al = {"s": 2.5, "R": random_rotation(rng), "t": rng.normal(size=3) * 10}
    R, t = xs.reference_pose_in_map_frame(R_q, t_q, al)
    for _ in range(10):
        x_joint = rng.normal(size=3) * 4
        x_map = al["s"] * al["R"] @ x_joint + al["t"]
        assert np.allclose(R @ x_map + t, al["s"] * (R_q @ x_joint + t_q))


def test_rotation_to_quaternion_at_180_degrees():
    for R in (np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1]),
              np.array([[0.0, -1, 0], [-1, 0, 0], [0, 0, -1]]), np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])):
        assert np.allclose(xs.quat_to_rot(xs.rot_to_quat(R)), R, atol=1e-12), R


def write_scene(root, scene, photos):
    d = root / "strecha" / scene
    (d / "images").mkdir(parents=True)
    (d / "cameras").mkdir()
    for name, data in photos.items():
        (d / "images" / name).write_bytes(data)
        K, R, C = "1000 0 500 0 1000 400 0 0 1", "1 0 0 0 1 0 0 0 1", "0 0 0"
        (d / "cameras" / (name + ".camera")).write_text(f"{K}\n0 0 0\n{R}\n{C}\n1000 800\n")


def test_pair_inputs_leave_out_identical_photos_and_photos_without_a_reference(tmp_path):
    write_scene(tmp_path, "A", {"0000.jpg": b"same photo", "0001.jpg": b"a"})
    write_scene(tmp_path, "B", {"0000.jpg": b"b0", "0001.jpg": b"same photo", "0002.jpg": b"b2"})
    args = type("Args", (), {"shared_data": tmp_path})()
    R_q, t_q = xs.quat_to_rot(np.array([0.9, 0.1, -0.3, 0.2])), np.array([1.0, 2.0, 3.0])
    # B's 0000 and 0001 are in A's model; 0002 is not (no reference).
    models = [({"B__0000.jpg": (R_q, t_q, 1), "B__0001.jpg": (np.eye(3), np.zeros(3), 2)}, [])]
    alignment = {"A": {"model": 0, "s": 2.0, "R": np.eye(3), "t": np.array([0.0, 0, 1])}, "B": {"model": None}}
    queries, identical, unscored = xs.write_pair_inputs(args, tmp_path / "pair", models, alignment, "A", "B")
    assert (queries, identical, unscored) == (["0000.jpg"], ["0001.jpg"], ["0002.jpg"])
    line = (tmp_path / "pair" / "truth.txt").read_text().split()
    assert line[0] == "0000.jpg"
    R, t = xs.quat_to_rot(np.array([float(x) for x in line[1:5]])), np.array([float(x) for x in line[5:8]])
    R_ref, t_ref = xs.reference_pose_in_map_frame(R_q, t_q, alignment["A"])
    assert np.allclose(R, R_ref) and np.allclose(t, t_ref)
    assert (tmp_path / "pair" / "intrinsics.txt").read_text().split() == \
        ["0000.jpg", "PINHOLE", "1000", "800", "1000.0", "1000.0", "500.5", "400.5"]
