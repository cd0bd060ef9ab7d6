"""The WGS84 anchor of a map as the command line gives it (`--anchor`) or the bundle records it.

The transform itself is terra.wgs84.MapToWgs84.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from terra.errors import TerraError
from terra.schemas import Wgs84Anchor

if TYPE_CHECKING:
    from terra.bundle import Bundle

ANCHOR_FORMAT = "LAT,LON[,ALT[,YAW_DEG]]"


def parse_anchor(text: str) -> Wgs84Anchor:
    """The anchor of `--anchor LAT,LON[,ALT[,YAW_DEG]]` (degrees, metres); TerraError naming what is wrong."""
    words = [w.strip() for w in text.split(",")]
    try:
        numbers = [float(w) for w in words]
    except ValueError:
        raise TerraError(f"--anchor {text!r}: expected numbers {ANCHOR_FORMAT}") from None
    if not 2 <= len(numbers) <= 4 or not all(math.isfinite(v) for v in numbers):
        raise TerraError(f"--anchor {text!r}: expected 2 to 4 finite numbers {ANCHOR_FORMAT}")
    lat, lon, alt, yaw = [*numbers, 0.0, 0.0][:4]
    if abs(lat) >= 90.0 or abs(lon) > 180.0:
        raise TerraError(f"--anchor {text!r}: latitude {lat} / longitude {lon} out of range (degrees)")
    return Wgs84Anchor(lat=lat, lon=lon, alt=alt, yaw_deg=yaw, source="--anchor")


def bundle_anchor(bundle: Bundle) -> Wgs84Anchor | None:
    """The anchor the bundle's manifest records (components.map.wgs84_anchor), or None."""
    info = bundle.model.components.map
    return None if info is None else info.wgs84_anchor


def resolve_anchor(bundle: Bundle, text: str | None) -> Wgs84Anchor:
    """`--anchor` when given, else the bundle's; TerraError when neither is known."""
    if text is not None:
        return parse_anchor(text)
    anchor = bundle_anchor(bundle)
    if anchor is None:
        raise TerraError(
            f"{bundle.path}: the map has no WGS84 anchor (manifest.json components.map.wgs84_anchor); "
            f"give one with --anchor {ANCHOR_FORMAT}"
        )
    return anchor
