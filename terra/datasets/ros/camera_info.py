"""sensor_msgs/CameraInfo -> CameraCalibration (intrinsics, lens model, image size).

ROS 2 names the arrays d, k, r, p; ROS 1 names them D, K, R, P. `distortion_model` is one of
terra.lens.ROS_DISTORTION_MODELS (plumb_bob, rational_polynomial, equidistant); an empty D means
an ideal (rectified) lens whatever the model says.
"""

from __future__ import annotations

import numpy as np

from terra import lens
from terra.errors import TerraError
from terra.geometry import CameraCalibration


def _array(msg, name: str) -> np.ndarray:
    value = getattr(msg, name, None)
    if value is None:
        value = getattr(msg, name.upper())
    return np.asarray(value, dtype=np.float64).ravel()


def camera_from_info(
    msg, name: str, T_cam_lidar: np.ndarray, where: str = "CameraInfo", image_size: tuple[int, int] | None = None
) -> CameraCalibration:
    """The calibration a CameraInfo states, with extrinsics T_cam_lidar (4x4, LiDAR -> optical
    frame, metres). `image_size` (width, height) of the camera's images, when known: it fills a
    CameraInfo that leaves the size 0 and must match one that states it. TerraError naming the
    field for an uncalibrated or unsupported camera."""
    K = _array(msg, "k")
    if K.size != 9 or K[0] == 0.0 or K[4] == 0.0:
        raise TerraError(f"{where}: field 'k' is {K.tolist()}; expected the 3x3 intrinsics of a calibrated camera")
    model_name = str(msg.distortion_model)
    dist = _array(msg, "d")
    if dist.size == 0 or not np.any(dist):
        model, dist = lens.PINHOLE, np.zeros(0)
    elif model_name in lens.ROS_DISTORTION_MODELS:
        model, counts = lens.ROS_DISTORTION_MODELS[model_name]
        if dist.size not in counts and dist.size not in lens.COEFFICIENT_COUNTS[model]:
            raise TerraError(
                f"{where}: distortion_model '{model_name}' with {dist.size} coefficients in 'd'; expected "
                f"{' or '.join(str(c) for c in counts)}"
            )
    else:
        raise TerraError(
            f"{where}: distortion_model '{model_name}' is not supported; expected one of: "
            f"{', '.join(lens.ROS_DISTORTION_MODELS)}"
        )
    width, height = int(msg.width), int(msg.height)
    if image_size is not None:
        if (width, height) == (0, 0):
            width, height = image_size
        elif (width, height) != tuple(image_size):
            raise TerraError(
                f"{where}: width x height {width}x{height}, but the camera's images are {image_size[0]}x{image_size[1]}"
            )
    try:
        return CameraCalibration(
            name, width, height, K.reshape(3, 3) / K[8] if K[8] else K.reshape(3, 3), dist, T_cam_lidar, model
        )
    except ValueError as exc:
        raise TerraError(f"{where}: {exc}") from None
