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
