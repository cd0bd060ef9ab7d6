"""Lens models against OpenCV (a test-only reference): projection and its inverse over whole images."""

from __future__ import annotations

import numpy as np
import pytest

from terra import lens
from terra.geometry import CameraCalibration, pixel_rays, project_points

cv2 = pytest.importorskip("cv2")

W, H = 768, 480
K = np.array([[458.17091039, 0.0, 388.71610935], [0.0, 457.99950521, 230.87195191], [0.0, 0.0, 1.0]])

# Realistic coefficient vectors of every length OpenCV uses (the 4-coefficient one is a real
# calibration of a 768 x 480 field camera).
PINHOLE_LENSES = {
    4: np.array([0.03738764, -0.07371669, -0.00024887, 0.00058859]),
    5: np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]),
    8: np.array([0.12, -0.05, 0.0007, -0.0004, 0.01, 0.15, -0.03, 0.02]),
    12: np.array([0.12, -0.05, 0.0007, -0.0004, 0.01, 0.15, -0.03, 0.02, 0.0012, -0.0003, 0.0009, 0.0002]),
    14: np.array(
        [0.12, -0.05, 0.0007, -0.0004, 0.01, 0.15, -0.03, 0.02, 0.0012, -0.0003, 0.0009, 0.0002, 0.004, -0.003]
    ),
}
FISHEYE = np.array([0.0215, -0.0087, 0.0031, -0.0008])


def _authors_lenses() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The six real 768 x 480 lenses of the authors' configs: three with 4 coefficients, three
    with 14 (rational + thin prism + tilt; k1 up to 16 with a nearly cancelling denominator)."""
    import yaml

    from tests.datasets.fixtures_authors import NUNNS_PARK_YAML, SSP_YAML

    out = {}
    for rig, text in (("ssp", SSP_YAML), ("nunns-park", NUNNS_PARK_YAML)):
        cfg = yaml.safe_load(text)
        for n in (1, 2, 3):
            out[f"{rig}-cam{n}"] = (np.reshape(cfg[f"cam{n}_K"], (3, 3)), np.asarray(cfg[f"cam{n}_dist"], dtype=float))
    return out


AUTHORS_LENSES = _authors_lenses()


def _pixels(step: int = 8) -> np.ndarray:
    u, v = np.meshgrid(np.arange(-0.5, W, step, dtype=float), np.arange(-0.5, H, step, dtype=float))
    return np.stack([u.ravel(), v.ravel()], axis=1)


def _cv_project(points: np.ndarray, dist: np.ndarray, model: str) -> np.ndarray:
    if model == lens.FISHEYE:
        out, _ = cv2.fisheye.projectPoints(points[:, None, :], np.zeros(3), np.zeros(3), K, np.asarray(dist))
    else:
        out, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, np.asarray(dist))
    return out.reshape(-1, 2)


@pytest.mark.parametrize("count", sorted(PINHOLE_LENSES))
def test_pinhole_projection_and_inverse_match_opencv(count):
    dist = PINHOLE_LENSES[count]
    cam = CameraCalibration("c", W, H, K, dist)
    rays = pixel_rays(cam)  # inverse over every pixel of the image
    uv, valid = project_points(rays * 9.0, cam)
    assert valid.all()
    v, u = np.mgrid[0:H, 0:W]
    np.testing.assert_allclose(uv, np.stack([u.ravel(), v.ravel()], 1), atol=1e-6)
    sample = rays[::97] * 9.0
    np.testing.assert_allclose(project_points(sample, cam)[0], _cv_project(sample, dist, lens.PINHOLE), atol=1e-6)


@pytest.mark.parametrize("count", sorted(PINHOLE_LENSES))
def test_pinhole_undistort_matches_opencv_iterative(count):
    dist = np.asarray(PINHOLE_LENSES[count])
    pixels = _pixels()
    cam = CameraCalibration("c", W, H, K, dist)
    ours = lens.undistort(cam.pixels_to_normalized(pixels), dist)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-15)
    theirs = cv2.undistortPoints(pixels[:, None, :], K, dist, criteria=criteria).reshape(-1, 2)
    # Where OpenCV's fixed-point iteration converged (its own round trip is exact), both agree.
    back = _cv_project(np.concatenate([theirs, np.ones((len(theirs), 1))], 1), dist, lens.PINHOLE)
    converged = np.abs(back - pixels).max(axis=1) < 1e-7
    assert converged.mean() > 0.9
    np.testing.assert_allclose(ours[converged] * K[0, 0], theirs[converged] * K[0, 0], atol=1e-6)


def test_fisheye_projection_and_inverse_match_opencv():
    cam = CameraCalibration("f", W, H, K, FISHEYE, model=lens.FISHEYE)
    rays = pixel_rays(cam)
    uv, valid = project_points(rays * 5.0, cam)
    assert valid.all()
    v, u = np.mgrid[0:H, 0:W]
    np.testing.assert_allclose(uv, np.stack([u.ravel(), v.ravel()], 1), atol=1e-6)
    sample = rays[::89] * 5.0
    np.testing.assert_allclose(project_points(sample, cam)[0], _cv_project(sample, FISHEYE, lens.FISHEYE), atol=1e-6)
    pixels = _pixels()
    theirs = cv2.fisheye.undistortPoints(
        pixels[:, None, :],
        K,
        np.asarray(FISHEYE),
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15),
    ).reshape(-1, 2)
    ours = lens.undistort(cam.pixels_to_normalized(pixels), FISHEYE, lens.FISHEYE)
    np.testing.assert_allclose(ours * K[0, 0], theirs * K[0, 0], atol=1e-6)


def test_rays_beyond_the_field_of_view_never_fold_into_the_image():
    # The radial polynomial turns back beyond the image's field of view (r_d = r (1 + 0.1 r^2 -
    # 0.05 r^4) peaks at r = 1.64), so a ray 66 degrees off axis (r = 2.3) distorts onto a pixel
    # inside the image unless it is refused.
    dist = np.array([0.1, -0.05, 0.0, 0.0, 0.0])
    cam = CameraCalibration("b", W, H, K, dist)
    far = np.array([[2.3, 0.0, 1.0]])
    folded = lens.distort(far[:, :2], dist)[0, 0] * K[0, 0] + K[0, 2]
    assert -0.5 <= folded < W - 0.5  # the model alone puts it inside the image
    assert not project_points(far, cam)[1][0]
    corner = pixel_rays(cam)[-1:] * 4.0  # the image's own corner ray is still visible
    assert project_points(corner, cam)[1][0]


@pytest.mark.parametrize(
    "model,dist,message",
    [
        (lens.PINHOLE, [0.1, 0.2, 0.3], "supported lengths: 0, 4, 5, 8, 12, 14"),
        (lens.PINHOLE, [0.1] * 6, "supported lengths: 0, 4, 5, 8, 12, 14"),
        (lens.FISHEYE, [0.1] * 5, "supported lengths: 4"),
        ("kannala", [0.1] * 4, "unknown lens model"),
        (lens.PINHOLE, [0.1, np.nan, 0.0, 0.0], "finite"),
    ],
)
def test_unsupported_coefficients_are_named(model, dist, message):
    with pytest.raises(ValueError, match=message):
        CameraCalibration("c", W, H, K, dist, model=model)


@pytest.mark.parametrize("name", sorted(AUTHORS_LENSES))
def test_the_authors_lenses_match_opencv_over_the_whole_image(name):
    K_real, dist = AUTHORS_LENSES[name]
    cam = CameraCalibration(name, W, H, K_real, dist)
    rays = pixel_rays(cam)  # the inverse at every pixel centre
    uv, valid = project_points(rays * 7.0, cam)
    assert valid.all()
    v, u = np.mgrid[0:H, 0:W]
    np.testing.assert_allclose(uv, np.stack([u.ravel(), v.ravel()], 1), atol=1e-6)
    sample = rays[::53] * 7.0
    theirs, _ = cv2.projectPoints(sample, np.zeros(3), np.zeros(3), K_real, np.asarray(dist))
    np.testing.assert_allclose(project_points(sample, cam)[0], theirs.reshape(-1, 2), atol=1e-6)
    pixels = _pixels()
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-15)
    undistorted = cv2.undistortPoints(pixels[:, None, :], K_real, np.asarray(dist), criteria=criteria).reshape(-1, 2)
    back, _ = cv2.projectPoints(
        np.concatenate([undistorted, np.ones((len(pixels), 1))], 1), np.zeros(3), np.zeros(3), K_real, np.asarray(dist)
    )
    converged = np.abs(back.reshape(-1, 2) - pixels).max(axis=1) < 1e-7
    assert converged.mean() > 0.9
    ours = lens.undistort(cam.pixels_to_normalized(pixels), dist)
    np.testing.assert_allclose(ours[converged] * K_real[0, 0], undistorted[converged] * K_real[0, 0], atol=1e-6)
