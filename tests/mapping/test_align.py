"""Registration of a session to a map (terra/mapping/align.py) on clouds built by hand: a known transform
recovered, a non-overlapping pair refused, and the overlap and fitness measures against hand-worked values."""

from __future__ import annotations

import numpy as np
import pytest

from terra.errors import TerraError
from terra.geometry import invert_pose, transform_points
from terra.mapping.align import (
    AlignSettings,
    check_alignment,
    judge,
    parse_guess,
    pose_from_guess,
    register,
    thin,
)
from terra.mapping.sessions import find_alignment, relative_error


def scene(seed: int, size: float = 40.0) -> np.ndarray:
    """Ground (a grid every 0.25 m over size x size metres) with walls and boxes of random sizes, points on
    their surfaces every 0.2 m: (N, 3) metres."""
    rng = np.random.default_rng(seed)
    g = np.arange(0.0, size, 0.25)
    gx, gy = np.meshgrid(g, g)
    parts = [np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)]
    for _ in range(14):
        cx, cy = rng.uniform(2.0, size - 2.0, 2)
        sx, sy, sz = rng.uniform(0.5, 4.0), rng.uniform(0.5, 4.0), rng.uniform(1.0, 3.0)
        u = np.arange(-1.0, 1.0001, 0.2 / max(sx, sy))
        h = np.arange(0.0, sz, 0.2)
        uu, hh = np.meshgrid(u, h)
        for side in (-1.0, 1.0):  # four upright faces of the box
            parts.append(np.stack([cx + side * sx * np.ones(uu.size), cy + sy * uu.ravel(), hh.ravel()], axis=1))
            parts.append(np.stack([cx + sx * uu.ravel(), cy + side * sy * np.ones(uu.size), hh.ravel()], axis=1))
    return np.concatenate(parts)


def test_parse_guess_gives_the_planar_pose():
    T = parse_guess("50, -10, 90")
    np.testing.assert_allclose(T[:3, 3], [50.0, -10.0, 0.0])
    np.testing.assert_allclose(T[:3, :3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)  # x turned to y
    for bad in ("50,10", "a,b,c", "1,2,nan"):
        with pytest.raises(TerraError, match="--initial-guess .*expected x,y,yaw"):
            parse_guess(bad)


def test_thin_keeps_one_centroid_per_voxel():
    points = np.array([[0.1, 0.1, 0.1], [0.3, 0.3, 0.3], [1.5, 0.2, 0.2]])
    np.testing.assert_allclose(thin(points, 1.0), [[0.2, 0.2, 0.2], [1.5, 0.2, 0.2]])


def test_judge_counts_overlap_and_fitness_by_hand():
    map_points = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [20.0, 0.0, 0.0], [30.0, 0.0, 0.0]])
    # Session points 0.1 m, 0.2 m and 0.6 m from a map point, and one 5 m from any.
    session = np.array([[0.1, 0.0, 0.0], [10.0, 0.2, 0.0], [20.0, 0.0, 0.6], [35.0, 0.0, 0.0]])
    overlap, fitness, rmse = judge(map_points, session, np.eye(4), AlignSettings())
    assert overlap == pytest.approx(3 / 4)  # within 1 m
    assert fitness == pytest.approx(2 / 3)  # of those, within 0.3 m
    assert rmse == pytest.approx(np.sqrt((0.01 + 0.04 + 0.36) / 3))


def test_register_recovers_a_known_transform_from_a_rough_guess():
    world = scene(1)
    T_map_session = pose_from_guess(25.0, -8.0, 70.0)
    # The session saw the part of the world with x > 12 m, in its own frame.
    session = transform_points(invert_pose(T_map_session), world[world[:, 0] > 12.0])
    alignment = register(world, thin(session, 0.2), pose_from_guess(23.0, -6.5, 62.0), "initial guess", AlignSettings())
    check_alignment(alignment, AlignSettings(), "session")  # accepted: no error
    metres, degrees = relative_error(T_map_session, alignment.T_map_session)
    assert metres < 0.02 and degrees < 0.05
    assert alignment.how == "initial guess + GICP" and alignment.overlap > 0.95 and alignment.fitness > 0.95


def test_a_session_of_another_place_is_refused_with_its_fitness_and_overlap():
    world, elsewhere = scene(1), scene(2)
    elsewhere = elsewhere[elsewhere[:, 2] > 0.1]  # its walls only: nothing of it lies in the map
    alignment = register(world, thin(elsewhere, 0.2), np.eye(4), "shared frame", AlignSettings())
    with pytest.raises(TerraError) as error:
        check_alignment(alignment, AlignSettings(), "visit2")
    message = str(error.value)
    assert "\n" not in message and message.startswith("visit2: cannot align the session to the map: ")
    assert f"fitness {alignment.fitness:.2f}" in message and f"overlap {alignment.overlap:.2f}" in message
    assert "nothing merged" in message


def test_without_a_guess_the_footprint_search_finds_a_drive_50_m_and_90_degrees_away():
    world = scene(1)
    T_map_session = pose_from_guess(50.0, -10.0, 90.0)
    session = thin(transform_points(invert_pose(T_map_session), world[world[:, 0] > 12.0]), 0.2)
    alignment = find_alignment(world, session, None, AlignSettings(), "session")
    metres, degrees = relative_error(T_map_session, alignment.T_map_session)
    assert metres < 0.02 and degrees < 0.05 and alignment.how == "place search + GICP"
