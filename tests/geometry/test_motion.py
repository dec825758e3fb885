"""Kinematic bodies: poses, rigid velocities and posed distances against closed forms."""

import numpy as np
import pytest

from windbench.cli import compose_config
from windbench.errors import ConfigError
from windbench.geometry.bodies import (
    MOVING,
    POSE,
    PREVIOUS,
    body_from_config,
    body_table,
    distances,
    set_poses,
)
from windbench.geometry.motion import axis_rotation, motion_from_config
from windbench.scenes import build_scene

BOX = {"type": "box", "min": [0, 0, 0], "max": [2, 1, 1]}
KEYS = {"type": "keyframes", "times": [1.0, 3.0], "positions": [[0, 0, 0], [2, 0, 0]]}


def test_keyframe_pose_at_keyframes_midway_and_held():
    motion = motion_from_config(
        {**KEYS, "rotations": [0.0, 90.0], "pivot": [1, 0, 0]}, "scene.bodies[0].motion"
    )
    for t, disp, angle in [(0.0, 0, 0), (1.0, 0, 0), (2.0, 1, 45), (3.0, 2, 90), (9.0, 2, 90)]:
        pose = motion.pose(t)
        np.testing.assert_allclose(pose.centre, [1 + disp, 0, 0], atol=1e-15)
        a = np.radians(angle)
        rz = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        np.testing.assert_allclose(pose.rotation, rz, atol=1e-15)
    mid = motion.pose(2.0)  # rates: 1 m/s along x, 45 deg/s about z
    np.testing.assert_allclose(mid.velocity, [1, 0, 0])
    np.testing.assert_allclose(mid.omega, [0, 0, np.radians(45)])
    np.testing.assert_array_equal(motion.pose(0.5).omega, 0.0)  # held before the first


def test_rotation_velocity_is_omega_cross_the_lever_arm():
    spec = {"type": "rotation", "axis": [0, 0, 2], "point": [1, 0, 0], "angular_speed": 2.0}
    motion = motion_from_config({**spec, "start": 1.0, "stop": 2.0}, "m")
    pose = motion.pose(1.5)
    np.testing.assert_allclose(pose.point_velocity([[1, 1, 5], [3, 0, 0]]), [[-2, 0, 0], [0, 4, 0]])
    # the velocity is the time derivative of a material point's path
    x0 = np.array([[2.0, 0.5, 0.3]])
    h = 1e-6
    fd = (motion.pose(1.5 + h).to_world(x0) - motion.pose(1.5 - h).to_world(x0)) / (2 * h)
    np.testing.assert_allclose(pose.point_velocity(pose.to_world(x0)), fd, rtol=1e-8)
    np.testing.assert_allclose(motion.pose(5.0).rotation, axis_rotation(np.array([0, 0, 1.0]), 2))
    np.testing.assert_array_equal(motion.pose(5.0).omega, 0.0)  # stopped


@pytest.mark.parametrize("t", [0.0, 1.7, 2.6, 4.0])
def test_posed_box_distance_is_the_rest_box_at_the_carried_back_point(t):
    motion = {**KEYS, "rotations": [10.0, 130.0], "axis": [1, 1, 1]}
    moving = body_from_config({**BOX, "motion": motion}, "b")
    still = body_from_config(BOX, "b")
    pose = moving.motion.pose(t)
    x = np.random.default_rng(1).uniform(-2, 4, (300, 3))
    x0 = (x - pose.centre) @ pose.rotation + pose.pivot  # R^T (x - c) + P
    d, n = distances([moving], x, time=t)
    d0, n0 = distances([still], x0)
    np.testing.assert_allclose(d, d0, atol=1e-12)
    np.testing.assert_allclose(n, n0 @ pose.rotation.T, atol=1e-12)


def test_a_still_body_reads_as_before_and_poses_advance():
    still = body_from_config(BOX, "b")
    spin = {"type": "rotation", "axis": [0, 0, 1], "point": [0, 0, 0], "angular_speed": 1.0}
    moving = body_from_config({**BOX, "motion": spin}, "m")
    table = body_table([still, moving], time=0.0)
    assert table.params[:, MOVING].tolist() == [0.0, 1.0]
    np.testing.assert_array_equal(table.params[0, MOVING:], 0.0)
    set_poses(table, [still, moving], 0.5)
    np.testing.assert_array_equal(table.params[1, PREVIOUS:], moving.motion.pose(0.0).row())
    np.testing.assert_array_equal(table.params[1, POSE:PREVIOUS], moving.motion.pose(0.5).row())


@pytest.mark.parametrize(
    "motion, match",
    [
        ({"type": "spin"}, r"b.motion.type: must be one of \['keyframes', 'rotation'\]"),
        ({**KEYS, "speed": 1}, r"b.motion: unknown key\(s\) \['speed'\]"),
        ({**KEYS, "times": [1.0, 1.0]}, r"b.motion.times: must increase strictly"),
        ({**KEYS, "rotations": [0.0]}, r"b.motion.rotations: must have one entry per time"),
        ({**KEYS, "positions": [[0, 0], [1, 0, 0]]}, r"b.motion.positions\[0\]: must be 3"),
        ({"type": "rotation", "axis": [0, 0, 1], "point": [0, 0, 0]}, r"angular_speed: is req"),
        (
            {"type": "rotation", "axis": [0, 0, 0], "point": [0, 0, 0], "angular_speed": 1},
            r"b.motion.axis: must be a non-zero vector",
        ),
    ],
)
def test_bad_motions_name_the_key(motion, match):
    with pytest.raises(ConfigError, match=match):
        body_from_config({**BOX, "motion": motion}, "b")


def test_a_plane_needs_a_pivot_for_keyframes():
    plane = {"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}
    with pytest.raises(ConfigError, match=r"p.motion.pivot: is required"):
        body_from_config({**plane, "motion": KEYS}, "p")


def test_the_turning_shirt_scene_ends_facing_into_its_wind():
    """conf/scene/shirt_turning: the character (its mesh faces -x) stands side-on to the
    wind at first and faces into it, against the source's velocity, after the turn."""
    scene = build_scene(compose_config(["scene=shirt_turning"]).scene)
    motion = scene.bodies[0].motion
    wind = np.asarray(scene.sources[0].velocity)
    into_wind = -wind / np.linalg.norm(wind)
    facing = [motion.pose(t).rotation @ [-1.0, 0.0, 0.0] for t in (0.0, motion.times[-1])]
    assert abs(facing[0] @ into_wind) < 1e-12
    np.testing.assert_allclose(facing[1], into_wind, atol=1e-12)
