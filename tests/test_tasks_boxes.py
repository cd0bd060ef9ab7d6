"""Oriented box fitting on point sets with a known answer."""

from __future__ import annotations

import numpy as np
import pytest

from terra.tasks.boxes import fit_oriented_box, wrap_half_turn
from tests.test_tasks_synthetic import box_points


@pytest.mark.parametrize("yaw", [np.radians(30.0), np.radians(120.0), np.radians(-75.0), 0.0])
def test_box_of_a_rotated_rectangle(yaw):
    center = np.array([12.5, -4.0, 1.0])
    points = box_points(center, (4.0, 2.0, 1.6), yaw)
    rng = np.random.default_rng(0)
    box = fit_oriented_box(rng.permutation(points))
    np.testing.assert_allclose(box.center, center, atol=1e-9)
    np.testing.assert_allclose(box.size, [4.0, 2.0, 1.6], atol=1e-9)
    # The long side is the x axis; yaw is folded into [-pi/2, pi/2).
    expected = wrap_half_turn(yaw)
    assert -np.pi / 2 <= box.yaw < np.pi / 2
    assert box.yaw == pytest.approx(expected, abs=1e-9)
    # Its corners are the rectangle's corners.
    c, s = np.cos(yaw), np.sin(yaw)
    true = np.array([[sx * 2.0, sy * 1.0] for sx, sy in [(-1, -1), (1, -1), (1, 1), (-1, 1)]]) @ np.array([[c, s], [-s, c]]) + center[:2]
    got = box.corners_xy()
    assert np.max(np.min(np.linalg.norm(got[:, None] - true[None], axis=2), axis=1)) < 1e-9


def test_wrap_half_turn_values():
    assert wrap_half_turn(np.radians(120)) == pytest.approx(np.radians(-60))
    assert wrap_half_turn(np.pi / 2) == pytest.approx(-np.pi / 2)
    assert wrap_half_turn(-np.pi) == pytest.approx(0.0)


def test_padding_and_degenerate_point_sets():
    line = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.5], [2.0, 2.0, 1.0]])
    box = fit_oriented_box(line, padding=0.2)
    assert box.yaw == pytest.approx(np.pi / 4)
    np.testing.assert_allclose(box.size, [np.sqrt(8) + 0.2, 0.2, 1.2])
    np.testing.assert_allclose(box.center, [1.0, 1.0, 0.5])
    single = fit_oriented_box(np.array([[3.0, 4.0, 5.0]]))
    np.testing.assert_allclose(single.center, [3, 4, 5])
    np.testing.assert_allclose(single.size, [0, 0, 0])
    with pytest.raises(ValueError):
        fit_oriented_box(np.zeros((0, 3)))



def test_many_groups_in_one_call_equal_one_at_a_time():
    from terra.tasks.boxes import fit_oriented_boxes

    rng = np.random.default_rng(5)
    sets = [rng.normal(size=(n, 3)) * [3, 1, 0.5] + rng.uniform(-20, 20, 3) for n in (3, 10, 57)]
    sets.append(np.array([[1.0, 1.0, 0.0], [2.0, 2.0, 1.0]]))  # collinear
    sets.append(np.array([[4.0, -1.0, 2.0]]))  # single point
    points = np.vstack(sets)
    groups = np.concatenate([np.full(len(s), g) for g, s in enumerate(sets)])
    shuffle = rng.permutation(len(points))
    boxes = fit_oriented_boxes(points[shuffle], groups[shuffle], padding=0.1)
    for box, s in zip(boxes, sets):
        one = fit_oriented_box(s, padding=0.1)
        np.testing.assert_allclose(box.center, one.center, atol=1e-12)
        np.testing.assert_allclose(box.size, one.size, atol=1e-12)
        assert box.yaw == pytest.approx(one.yaw, abs=1e-12)
        # Every point lies inside its box (up to rounding).
        c, si = np.cos(box.yaw), np.sin(box.yaw)
        local = (s[:, :2] - box.center[:2]) @ np.array([[c, -si], [si, c]])
        assert np.all(np.abs(local) <= box.size[:2] / 2 + 1e-9)
