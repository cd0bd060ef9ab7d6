"""The simulator's label vocabulary: terrain, structure and object classes with render colours.

Ids are stable (files and tests rely on them). `semantickitti_id` is SemanticKITTI's own id where
the real dataset has a matching class; the others get ids from a legend written beside the data.
The table lives beside the dataset formats, below terra.sim, because the SemanticKITTI writer
colours its legend with it; terra.sim.classes is the simulator's name for it.
"""

from __future__ import annotations

import numpy as np

from terra.datasets.base import ClassTable, SemanticClass

# (id, name, terrain, SemanticKITTI id, RGB colour, LiDAR reflectance 0..1)
_ROWS: list[tuple[int, str, bool, int | None, tuple[int, int, int], float]] = [
    (0, "unlabeled", False, 0, (150, 190, 235), 0.0),
    (1, "sidewalk", True, 48, (190, 185, 175), 0.35),
    (2, "grass", True, 72, (80, 150, 60), 0.25),
    (3, "asphalt", True, 40, (70, 70, 75), 0.10),
    (4, "dirt", True, 49, (140, 105, 70), 0.30),
    (5, "water", True, None, (60, 110, 170), 0.02),
    (10, "building", False, 50, (185, 150, 120), 0.45),
    (11, "tree", False, 70, (40, 105, 40), 0.30),
    (20, "car", False, 10, (170, 30, 40), 0.60),
    (21, "bicycle", False, 11, (30, 60, 160), 0.50),
    (22, "bicycle rack", False, None, (150, 150, 160), 0.70),
    (23, "bench", False, None, (120, 80, 45), 0.40),
    (24, "trash can", False, None, (40, 90, 60), 0.40),
    (25, "street light", False, 80, (90, 90, 95), 0.60),
    (26, "dumpster", False, None, (30, 80, 150), 0.50),
    (27, "stop light", False, None, (225, 190, 40), 0.70),
    (28, "crosswalk", False, 60, (240, 240, 235), 0.80),
    (29, "fire hydrant", False, None, (210, 40, 30), 0.60),
    (30, "picnic table", False, None, (150, 100, 55), 0.40),
    (31, "stairs", False, None, (160, 160, 155), 0.40),
    (32, "bollard", False, None, (230, 200, 50), 0.70),
    (33, "street sign", False, 81, (30, 140, 60), 0.90),
    (34, "mailbox", False, None, (40, 70, 150), 0.60),
    (35, "planter", False, None, (130, 90, 70), 0.35),
    (36, "bus shelter", False, None, (110, 120, 130), 0.50),
    (37, "parking meter", False, None, (100, 100, 110), 0.60),
    (38, "fence", False, 51, (225, 120, 35), 0.55),  # a site fence; placed only by a revisit (issue 26)
]

SIM_CLASSES = ClassTable([SemanticClass(i, n, t, sk) for i, n, t, sk, _, _ in _ROWS])

_MAX_ID = max(r[0] for r in _ROWS)
CLASS_COLORS = np.zeros((_MAX_ID + 1, 3), dtype=np.uint8)
"""RGB render colour per class id (rows for unused ids stay black)."""
CLASS_REFLECTANCE = np.zeros(_MAX_ID + 1, dtype=np.float32)
"""LiDAR reflectance per class id, 0..1."""
for _id, _name, _t, _sk, _rgb, _refl in _ROWS:
    CLASS_COLORS[_id] = _rgb
    CLASS_REFLECTANCE[_id] = _refl

UNLABELED = 0


def class_id(name: str) -> int:
    """Id of a simulator class by name (KeyError for an unknown name)."""
    return SIM_CLASSES.by_name(name).id
