"""GNSS fixes of a bag: sensor_msgs/NavSatFix messages as terra.datasets.gnss.GnssFixes.

A message counts when its status says the receiver has a fix (status.status >= STATUS_FIX, 0) and its
latitude and longitude are finite and in range; the others (no fix yet, a receiver's NaN) are counted
as left out. The header stamp is the fix's time. The horizontal standard deviation is the root of the
mean of the east and north variances (position_covariance[0] and [4], ENU, m^2) when the covariance
type says they are known (APPROXIMATED or better), else unknown (NaN).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from terra.datasets.gnss import GnssFixes
from terra.datasets.ros.bag import Bag, stamps_seconds

NAVSATFIX = "sensor_msgs/msg/NavSatFix"
STATUS_FIX = 0  # sensor_msgs/NavSatStatus: -1 no fix, 0 fix, 1 SBAS, 2 GBAS
COVARIANCE_APPROXIMATED = 1


def fix_row(msg: Any) -> tuple[float, float, float, float, float] | None:
    """(stamp s, lat, lon degrees, alt m, horizontal std m or NaN) of one NavSatFix, or None when it
    holds no usable fix (module docstring)."""
    lat, lon, alt = float(msg.latitude), float(msg.longitude), float(msg.altitude)
    if int(msg.status.status) < STATUS_FIX or not (math.isfinite(lat) and math.isfinite(lon)):
        return None
    if abs(lat) > 90.0 or abs(lon) > 180.0:
        return None
    covariance = np.asarray(msg.position_covariance, dtype=np.float64).reshape(-1)
    std = math.nan
    if int(msg.position_covariance_type) >= COVARIANCE_APPROXIMATED and covariance.size == 9:
        variance = (covariance[0] + covariance[4]) / 2.0
        std = math.sqrt(variance) if math.isfinite(variance) and variance > 0 else math.nan
    return stamps_seconds(msg.header.stamp), lat, lon, alt if math.isfinite(alt) else 0.0, std


def choose_gnss(bag: Bag, topic: str | None) -> str | None:
    """The NavSatFix topic: `topic` when given (checked), else the bag's only one, else None (several
    receivers: the user names one with `dataset.gnss_topic`)."""
    if topic is not None:
        return bag.require(topic, (NAVSATFIX,), "GNSS fixes")
    found = bag.topics_of_type(NAVSATFIX)
    return found[0] if len(found) == 1 else None


def read_fixes(bag: Bag, topic: str) -> tuple[GnssFixes, int]:
    """(the usable fixes of `topic`, sorted by stamp; how many messages were left out). A receiver that
    never had a fix gives no fixes, and the drive no anchor: it is not an error."""
    rows, left_out = [], 0
    for _, log_ns, raw in bag.read([topic]):
        row = fix_row(bag.deserialize(raw, topic, f"{bag.path} {topic} at log time {log_ns * 1e-9:.3f} s"))
        if row is None:
            left_out += 1
        else:
            rows.append(row)
    table = np.asarray(rows, dtype=np.float64).reshape(-1, 5)
    table = table[np.argsort(table[:, 0], kind="stable")]
    return GnssFixes(*(np.ascontiguousarray(table[:, k]) for k in range(5))), left_out
