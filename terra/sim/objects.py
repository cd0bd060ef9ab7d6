"""Object models: each class is a small union of boxes, cylinders and ellipsoids.

A model is a list of parts in the object's own frame: x forward (its length), y left, z up from
the ground at the object's anchor. A part is (kind, centre (3,), half sizes (3,), yaw, colour or
None for the class colour). Parameters are drawn from `rng` so instances differ a little.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from terra.sim.primitives import BOX, CYLINDER, ELLIPSOID

Part = tuple[int, tuple[float, float, float], tuple[float, float, float], float, tuple[int, int, int] | None]

CAR_COLORS = [
    (170, 30, 40),
    (230, 230, 235),
    (25, 25, 30),
    (60, 70, 140),
    (140, 140, 150),
    (200, 170, 60),
    (40, 110, 70),
]
_DARK = (35, 35, 40)
_METAL = (120, 120, 128)
_WOOD = (130, 85, 45)


def _box(cx, cy, cz, sx, sy, sz, yaw=0.0, color=None) -> Part:
    """A box from its centre and full sizes."""
    return (BOX, (cx, cy, cz), (sx / 2, sy / 2, sz / 2), yaw, color)


def _cyl(cx, cy, z0, z1, r, color=None) -> Part:
    """A vertical cylinder from z0 to z1."""
    return (CYLINDER, (cx, cy, (z0 + z1) / 2), (r, r, (z1 - z0) / 2), 0.0, color)


def car(rng: np.random.Generator) -> list[Part]:
    length, width = rng.uniform(4.2, 4.8), rng.uniform(1.75, 1.9)
    color = CAR_COLORS[int(rng.integers(len(CAR_COLORS)))]
    cabin = rng.uniform(0.5, 0.6)
    wheels = [
        _box(sx * (length / 2 - 0.8), sy * (width / 2 - 0.12), 0.3, 0.62, 0.22, 0.6, color=_DARK)
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]
    return [
        _box(0.0, 0.0, 0.25 + 0.8 / 2, length, width, 0.8, color=color),
        _box(-0.15, 0.0, 1.05 + cabin / 2, length * 0.55, width * 0.9, cabin, color=(45, 55, 70)),
    ] + wheels


def bicycle(rng: np.random.Generator) -> list[Part]:
    color = CAR_COLORS[int(rng.integers(len(CAR_COLORS)))]
    return [
        _box(0.0, 0.0, 0.65, 1.0, 0.05, 0.45, color=color),
        _box(-0.55, 0.0, 0.36, 0.66, 0.04, 0.66, color=_DARK),
        _box(0.55, 0.0, 0.36, 0.66, 0.04, 0.66, color=_DARK),
        _box(0.45, 0.0, 1.0, 0.06, 0.55, 0.04, color=_DARK),
    ]


def bicycle_rack(rng: np.random.Generator, hoops: int = 4, spacing: float = 0.8) -> list[Part]:
    """Hoops spaced along x; a bicycle parks through each hoop, along y."""
    parts = []
    xs = (np.arange(hoops) - (hoops - 1) / 2) * spacing
    for x in xs:
        parts += [
            _box(x, -0.3, 0.42, 0.06, 0.06, 0.84),
            _box(x, 0.3, 0.42, 0.06, 0.06, 0.84),
            _box(x, 0.0, 0.86, 0.06, 0.66, 0.06),
        ]
    parts.append(_box(0.0, 0.0, 0.04, spacing * hoops, 0.08, 0.08))
    return parts


def bench(rng: np.random.Generator) -> list[Part]:
    """Seat along x; the back rest is on the -y side (the bench faces +y)."""
    return [
        _box(0.0, 0.0, 0.45, 1.7, 0.45, 0.06),
        _box(0.0, -0.21, 0.72, 1.7, 0.05, 0.42),
        _box(-0.75, 0.0, 0.21, 0.06, 0.45, 0.42, color=_METAL),
        _box(0.75, 0.0, 0.21, 0.06, 0.45, 0.42, color=_METAL),
    ]


def trash_can(rng: np.random.Generator) -> list[Part]:
    return [_cyl(0.0, 0.0, 0.0, 0.95, 0.3), _cyl(0.0, 0.0, 0.95, 1.0, 0.33, color=_DARK)]


def street_light(rng: np.random.Generator) -> list[Part]:
    """Pole at the origin; the arm reaches over +x."""
    h = rng.uniform(5.5, 6.5)
    return [
        _cyl(0.0, 0.0, 0.0, h, 0.1),
        _box(0.6, 0.0, h - 0.05, 1.2, 0.08, 0.08),
        _box(1.15, 0.0, h - 0.18, 0.5, 0.3, 0.16, color=(240, 235, 200)),
    ]


def dumpster(rng: np.random.Generator) -> list[Part]:
    return [_box(0.0, 0.0, 0.7, 1.9, 1.2, 1.4), _box(0.0, 0.0, 1.43, 2.0, 1.3, 0.06, color=_DARK)]


def stop_light(rng: np.random.Generator) -> list[Part]:
    """Pole with a signal head; the head faces +x."""
    return [
        _cyl(0.0, 0.0, 0.0, 3.0, 0.1, color=_METAL),
        _box(0.0, 0.0, 3.5, 0.35, 0.4, 1.0),
        _box(0.19, 0.0, 3.85, 0.04, 0.22, 0.22, color=(220, 40, 30)),
    ]


def crosswalk(rng: np.random.Generator, length: float = 10.0, width: float = 3.0) -> list[Part]:
    """Zebra bars along x (the walking direction) spread over `width`; pieces of <= 1 m follow the ground."""
    parts = []
    pieces = max(1, int(np.ceil(length)))
    xs = (np.arange(pieces) + 0.5) * (length / pieces) - length / 2
    for y in np.arange(-width / 2 + 0.3, width / 2 - 0.2, 0.75):
        for x in xs:
            parts.append(_box(x, y, 0.01, length / pieces, 0.45, 0.06))
    return parts


def fire_hydrant(rng: np.random.Generator) -> list[Part]:
    return [_cyl(0.0, 0.0, 0.0, 0.6, 0.14), _cyl(0.0, 0.0, 0.6, 0.75, 0.09), _box(0.0, 0.0, 0.45, 0.38, 0.09, 0.09)]


def picnic_table(rng: np.random.Generator) -> list[Part]:
    return [
        _box(0.0, 0.0, 0.75, 1.8, 0.8, 0.05),
        _box(0.0, 0.62, 0.45, 1.8, 0.3, 0.05),
        _box(0.0, -0.62, 0.45, 1.8, 0.3, 0.05),
        _box(-0.7, 0.0, 0.36, 0.08, 1.5, 0.72, color=_WOOD),
        _box(0.7, 0.0, 0.36, 0.08, 1.5, 0.72, color=_WOOD),
    ]


def stairs(
    rng: np.random.Generator, width: float = 4.0, steps: int = 3, tread: float = 0.35, rise: float = 0.15
) -> list[Part]:
    """Steps climb toward +y (the door); width along x."""
    depth = steps * tread
    return [
        _box(0.0, depth / 2 - (steps - k) * tread / 2, (k + 1) * rise / 2, width, (steps - k) * tread, (k + 1) * rise)
        for k in range(steps)
    ]


def bollard(rng: np.random.Generator) -> list[Part]:
    return [_cyl(0.0, 0.0, 0.0, 0.9, 0.1)]


def street_sign(rng: np.random.Generator) -> list[Part]:
    return [_cyl(0.0, 0.0, 0.0, 2.4, 0.04, color=_METAL), _box(0.0, 0.0, 2.55, 0.03, 0.8, 0.25)]


def mailbox(rng: np.random.Generator) -> list[Part]:
    return [_box(0.0, 0.0, 0.1, 0.5, 0.5, 0.2, color=_DARK), _box(0.0, 0.0, 0.7, 0.5, 0.5, 1.0)]


def planter(rng: np.random.Generator) -> list[Part]:
    return [_box(0.0, 0.0, 0.25, 1.2, 1.2, 0.5), (ELLIPSOID, (0.0, 0.0, 0.75), (0.5, 0.5, 0.35), 0.0, (60, 120, 50))]


def bus_shelter(rng: np.random.Generator) -> list[Part]:
    """Open toward +y; the back wall is on the -y side."""
    return [
        _box(0.0, 0.0, 2.5, 3.6, 1.6, 0.1),
        _box(0.0, -0.75, 1.225, 3.6, 0.06, 2.45, color=(150, 175, 190)),
        _box(-1.77, 0.0, 1.225, 0.06, 1.5, 2.45, color=(150, 175, 190)),
        _box(1.77, 0.0, 1.225, 0.06, 1.5, 2.45, color=(150, 175, 190)),
        _box(0.0, -0.45, 0.45, 2.5, 0.4, 0.06, color=_WOOD),
    ]


def parking_meter(rng: np.random.Generator) -> list[Part]:
    return [_cyl(0.0, 0.0, 0.0, 1.15, 0.05), _box(0.0, 0.0, 1.3, 0.2, 0.16, 0.34)]


def fence(
    rng: np.random.Generator, length: float = 3.0, height: float = 1.2, panel: float = 0.06, post: float = 0.1
) -> list[Part]:
    """A site fence along x, `length` metres end to end (its end posts' outer faces): square posts of side
    `post` at both ends and at most 2.5 m apart, `height` tall, and a mesh panel `panel` thick between them
    from 0.05 m above the ground to 0.05 m below the posts' tops."""
    span = max(length - post, 0.0)
    posts = np.linspace(-span / 2, span / 2, max(int(np.ceil(span / 2.5)), 1) + 1)
    parts = [_box(float(x), 0.0, height / 2, post, post, height, color=_METAL) for x in posts]
    parts.append(_box(0.0, 0.0, 0.05 + (height - 0.1) / 2, span, panel, height - 0.1))
    return parts


def tree(rng: np.random.Generator, scale: float = 1.0) -> list[Part]:
    trunk = rng.uniform(2.6, 3.4) * scale
    r = rng.uniform(2.0, 3.0) * scale
    rz = r * rng.uniform(0.9, 1.25)
    green = (int(rng.integers(30, 60)), int(rng.integers(95, 130)), int(rng.integers(30, 55)))
    return [
        _cyl(0.0, 0.0, 0.0, trunk + 0.5, 0.2 * scale, color=(90, 65, 40)),
        (ELLIPSOID, (0.0, 0.0, trunk + rz * 0.85), (r, r, rz), 0.0, green),
    ]


def building(
    rng: np.random.Generator,
    length: float = 20.0,
    depth: float = 12.0,
    height: float = 10.0,
    door: bool = True,
    sink: float = 0.0,
) -> list[Part]:
    """A box from -sink to height; a dark door on its -y face (the entrance side)."""
    tint = int(rng.integers(-25, 26))
    color = (185 + tint // 2, 150 + tint, 120 + tint)
    parts = [_box(0.0, 0.0, (height - sink) / 2, length, depth, height + sink, color=color)]
    if door:
        parts.append(_box(0.0, -depth / 2 - 0.03, 1.2, 2.0, 0.08, 2.4, color=(60, 45, 35)))
    return parts


MODELS: dict[str, Callable[..., list[Part]]] = {
    "car": car,
    "bicycle": bicycle,
    "bicycle rack": bicycle_rack,
    "bench": bench,
    "trash can": trash_can,
    "street light": street_light,
    "dumpster": dumpster,
    "stop light": stop_light,
    "crosswalk": crosswalk,
    "fire hydrant": fire_hydrant,
    "picnic table": picnic_table,
    "stairs": stairs,
    "bollard": bollard,
    "street sign": street_sign,
    "mailbox": mailbox,
    "planter": planter,
    "bus shelter": bus_shelter,
    "parking meter": parking_meter,
    "fence": fence,
    "tree": tree,
    "building": building,
}
"""Class name -> model function (rng, **params) -> parts."""
