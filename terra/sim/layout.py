"""Campus layouts: a grid of city blocks between roads, each block one kind of place.

A block of side B (block-local coordinates 0..B) has a 1.5 m grass verge along the road, then a
3 m perimeter sidewalk whose centre line (3 m in from the block edge) the robot follows. Block kinds:
- parking: a large parking lot surrounded by buildings on three sides;
- mall: two long parallel tree-lined sidewalks with benches, and a building;
- building: a building whose entrance plaza (stairs, bicycle racks, benches) is reached by an
  L-shaped sidewalk around a lawn (the lawn is the shortcut a planner takes unless told to prefer
  sidewalk), and a service pad with dumpsters behind it;
- park: a lawn with a pond, a dirt trail around it, picnic tables, benches and trees.
Intersections get crosswalks, stop lights and street signs; roads get street lights, trees,
hydrants and parked cars. `tiny_layout` is a single compact site for tests.
"""

from __future__ import annotations

import numpy as np
from shapely.affinity import scale as shp_scale
from shapely.geometry import Point, box

from terra.sim.builder import WorldBuilder

ROAD = 10.0
VERGE = 1.5
WALK = 3.0
PATH = VERGE + WALK / 2  # centre line of the perimeter sidewalk, from the block edge
INNER = VERGE + WALK  # start of the block interior, from the block edge
BLOCK_KINDS = ("parking", "mall", "building", "park")


class Block:
    """Block-local helper: converts local (u, v) in 0..B to map coordinates and back."""

    def __init__(self, b: WorldBuilder, x0: float, y0: float, size: float, index: tuple[int, int]) -> None:
        self.b, self.x0, self.y0, self.B, self.index = b, x0, y0, size, index

    def p(self, u: float, v: float) -> tuple[float, float]:
        return (self.x0 + u, self.y0 + v)

    def rect(self, u0: float, v0: float, u1: float, v1: float):
        return box(self.x0 + min(u0, u1), self.y0 + min(v0, v1), self.x0 + max(u0, u1), self.y0 + max(v0, v1))

    def paint(self, u0: float, v0: float, u1: float, v1: float, cls: str) -> None:
        self.b.paint(self.rect(u0, v0, u1, v1), cls)

    def add(self, cls: str, u: float, v: float, yaw: float = 0.0, **kw) -> int:
        return self.b.add(cls, self.x0 + u, self.y0 + v, yaw, **kw)

    def walkway(self, *uv: tuple[float, float]) -> None:
        self.b.walkway(*(self.p(u, v) for u, v in uv))

    def visit(self, *uv: tuple[float, float]) -> None:
        self.b.visit(*(self.p(u, v) for u, v in uv))

    def name(self, stem: str) -> str:
        return f"{stem}_{self.index[0]}_{self.index[1]}"


# ---------------------------------------------------------------------------------------- blocks
def perimeter(k: Block, driveways: tuple[tuple[str, float, float], ...] = ()) -> None:
    """Verge (grass) and perimeter sidewalk around the block; driveways cut through them
    as (side, centre, width) with side in 'S', 'N', 'W', 'E'."""
    B = k.B
    k.paint(VERGE, VERGE, B - VERGE, B - VERGE, "sidewalk")
    k.paint(INNER, INNER, B - INNER, B - INNER, "grass")
    for side, c, w in driveways:
        if side == "S":
            k.paint(c - w / 2, 0, c + w / 2, INNER, "asphalt")
        elif side == "N":
            k.paint(c - w / 2, B - INNER, c + w / 2, B, "asphalt")
    k.walkway((PATH, PATH), (B - PATH, PATH), (B - PATH, B - PATH), (PATH, B - PATH), (PATH, PATH))


def street_furniture(k: Block, avoid: list[tuple[str, float, float]]) -> None:
    """Street lights and trees alternating along the verge, one fire hydrant, cars parked along the roads."""
    B, rng = k.B, k.b.rng
    v = VERGE / 2
    stations = np.arange(14.0, B - 13.0, 12.0)
    for side in "SNWE":
        for i, s in enumerate(stations):
            if any(a == side and abs(s - c) < w / 2 + 3.0 for a, c, w in avoid):
                continue
            u, vv, yaw = {
                "S": (s, v, np.pi / 2),
                "N": (s, B - v, -np.pi / 2),
                "W": (v, s, 0.0),
                "E": (B - v, s, np.pi),
            }[side]
            if i % 2 == 0:
                k.add("street light", u, vv, yaw)
            else:
                k.add("tree", u, vv, scale=0.8)
    k.add("fire hydrant", 8.0, v)
    # Parked cars along the south and west roads, clear of the intersections and driveways.
    for side in "SW":
        for s in np.arange(18.0, B - 16.0, 6.5):
            if rng.random() > 0.45 or any(a == side and abs(s - c) < w / 2 + 4.0 for a, c, w in avoid):
                continue
            u, vv, yaw = {"S": (s, -1.3, 0.0), "W": (-1.3, s, np.pi / 2)}[side]
            k.add("car", u, vv, yaw + (np.pi if rng.random() < 0.5 else 0.0))


def parking_block(k: Block) -> None:
    B = k.B
    lot = (0.3 * B, INNER, 0.7 * B, 0.62 * B)
    mid = B / 2
    perimeter(k, (("S", mid, 8.0),))
    k.paint(lot[0] - WALK, INNER, lot[2] + WALK, lot[3] + WALK, "sidewalk")
    k.paint(*lot, "asphalt")
    top = _parking_buildings(k, lot)
    k.paint(mid - 2.5, lot[3] + WALK, mid + 2.5, top, "sidewalk")
    k.add("stairs", mid, top - 0.55, 0.0, width=3.0)
    k.add("trash can", mid + 3.2, top - 0.8)
    _parking_stalls(k, lot)
    for du in (-5.5, 5.5):
        k.add("bollard", mid + du, INNER + 1.0)
    k.add("parking meter", mid - 8.5, INNER + 1.0)
    for u in (lot[0] - WALK - 1.0, lot[2] + WALK + 1.0):
        for v in (INNER + 8.0, lot[3] - 4.0):
            k.add("street light", u, v, 0.0 if u < mid else np.pi)
    left, right, north = lot[0] - WALK / 2, lot[2] + WALK / 2, lot[3] + WALK / 2
    k.walkway((mid, PATH), (mid, north))
    k.walkway((left, PATH), (left, north), (right, north), (right, PATH))
    k.visit((mid, PATH), (mid, north), (left, north), (left, PATH))
    k.b.region(
        k.name("parking_lot"),
        "large parking lot surrounded by buildings",
        k.rect(lot[0] - WALK, INNER, lot[2] + WALK, lot[3] + WALK),
    )
    street_furniture(k, [("S", mid, 8.0)])


def _parking_buildings(k: Block, lot: tuple[float, float, float, float]) -> float:
    """Buildings west, north and east of the lot (u0, v0, u1, v1), lawns between; returns the v of
    the north building's front."""
    B, rng = k.B, k.b.rng
    mid = B / 2
    top = lot[3] + WALK + 2.0
    k.add(
        "building",
        INNER + 1.5 + (lot[0] - WALK - 2.0 - INNER - 1.5) / 2,
        B / 2,
        -np.pi / 2,
        length=0.7 * B,
        depth=lot[0] - WALK - 2.0 - INNER - 1.5,
        height=rng.uniform(8, 14),
        door=True,
    )
    k.add(
        "building",
        B - (INNER + 1.5 + (lot[0] - WALK - 2.0 - INNER - 1.5) / 2),
        B / 2,
        np.pi / 2,
        length=0.7 * B,
        depth=lot[0] - WALK - 2.0 - INNER - 1.5,
        height=rng.uniform(8, 14),
        door=True,
    )
    north_depth = B - INNER - 1.5 - top
    k.add(
        "building",
        mid,
        top + north_depth / 2,
        0.0,
        length=lot[2] - lot[0] + 2 * WALK,
        depth=north_depth,
        height=rng.uniform(10, 18),
        door=True,
    )
    return top


def _parking_stalls(k: Block, lot: tuple[float, float, float, float]) -> None:
    """Cars in the stalls: two rows along a north-south aisle, plus rows along the lot edges when
    it is wide."""
    rng = k.b.rng
    mid = k.B / 2
    rows = [(mid - 6.0, 0.0), (mid + 6.0, np.pi)]
    if lot[2] - lot[0] >= 40.0:
        rows += [(lot[0] + 2.5, np.pi), (lot[2] - 2.5, 0.0)]
    for u, yaw in rows:
        for v in np.arange(INNER + 7.0, lot[3] - 2.0, 2.7):
            if rng.random() < 0.65:
                k.add("car", u + rng.normal(0, 0.1), v, yaw + rng.normal(0, 0.03))


def mall_block(k: Block) -> None:
    B, rng = k.B, k.b.rng
    perimeter(k)
    ys = (0.33 * B, 0.63 * B)
    for y in ys:
        k.paint(INNER, y - 2.0, B - INNER, y + 2.0, "sidewalk")
        k.walkway((PATH, y), (B - PATH, y))
    xs = np.arange(INNER + 4.0, B - INNER - 2.0, 8.0)
    for y in ys:
        for side in (-1, 1):
            for x in xs:
                k.add("tree", x + rng.normal(0, 0.2), y + side * 3.6)
            for j, x in enumerate((xs[:-1] + xs[1:]) / 2):
                if j % 2 == (0 if side < 0 else 1):
                    k.add("bench", x, y + side * 3.0, np.pi if side > 0 else 0.0)
                    if j % 4 < 2:
                        k.add("trash can", x + 1.5, y + side * 3.2)
                elif j % 3 == 2:
                    k.add("street light", x, y + side * 2.9, -side * np.pi / 2)
    # A building north of the second walk, its entrance facing it.
    top = ys[1] + 7.0
    depth = B - INNER - 2.0 - top
    if depth >= 6.0:
        k.add("building", B / 2, top + depth / 2, 0.0, length=0.6 * B, depth=depth, height=rng.uniform(8, 16))
        k.paint(B / 2 - 2.0, ys[1] + 2.0, B / 2 + 2.0, top, "sidewalk")
        k.add("stairs", B / 2, top - 0.55, 0.0, width=3.0)
        k.add("bicycle rack", B / 2 + 4.0, top - 2.0, 0.0, hoops=4)
    south = box(k.x0 + INNER + 1, k.y0 + INNER + 1, k.x0 + B - INNER - 1, k.y0 + ys[0] - 5.0)
    k.b.scatter("picnic table", south, 2, 1.5)
    k.b.scatter("tree", south, int(B * B / 1500), 2.5)
    k.visit((PATH, ys[0]), (B - PATH, ys[0]), (B - PATH, ys[1]), (PATH, ys[1]))
    k.b.region(
        k.name("tree_lined_walks"),
        "two long parallel sidewalks lined by trees",
        k.rect(INNER, ys[0] - 4.5, B - INNER, ys[1] + 4.5),
    )
    street_furniture(k, [])


def building_block(k: Block) -> None:
    B, rng = k.B, k.b.rng
    mid = B / 2
    bw, bd = 0.5 * B, 0.28 * B
    y0 = 0.56 * B
    perimeter(k, (("N", mid, 10.0),))
    k.add("building", mid, y0 + bd / 2, 0.0, length=bw, depth=bd, height=rng.uniform(10, 20))
    k.add("stairs", mid, y0 - 0.55, 0.0, width=4.0)
    plaza = (mid - 7.0, y0 - 9.0, mid + 7.0, y0 - 1.05)
    k.paint(*plaza, "sidewalk")
    # The L-shaped walk from the plaza west, then south to the perimeter sidewalk.
    walk_y = plaza[1] + 3.5
    walk_x = INNER + 6.0
    k.paint(walk_x - WALK / 2, INNER, plaza[0], walk_y + WALK / 2, "sidewalk")
    k.paint(walk_x + WALK / 2, INNER, plaza[0], walk_y - WALK / 2, "grass")
    k.walkway((walk_x, PATH), (walk_x, walk_y), (mid, walk_y), (mid, y0 - 2.0))
    # Entrance furniture: bicycle racks with some bicycles, a bench, a trash can, a mailbox, planters.
    rack_x = mid + 5.2
    for v in (plaza[1] + 2.5, plaza[1] + 6.0):
        k.add("bicycle rack", rack_x, v, np.pi / 2, hoops=4)
        for hoop in range(4):
            if rng.random() < 0.5:
                k.add("bicycle", rack_x, v + (hoop - 1.5) * 0.8, 0.0)
    k.add("bench", mid - 5.5, plaza[1] + 5.5, -np.pi / 2)
    k.add("trash can", mid - 5.5, plaza[1] + 7.2)
    k.add("mailbox", plaza[2] - 0.6, plaza[1] + 0.6)
    for du in (-3.2, 3.2):
        k.add("planter", mid + du, y0 - 1.9)
    # Service pad behind the building, reached from the north road.
    pad = (mid - 6.0, y0 + bd + 1.0, mid + 6.0, B - INNER)
    k.paint(*pad, "asphalt")
    k.add("dumpster", mid - 3.0, pad[1] + 0.9, 0.0)
    k.add("dumpster", mid + 0.5, pad[1] + 0.9, 0.0)
    k.walkway((mid, B - PATH), (mid, pad[1] + 4.0))
    lawn = box(k.x0 + walk_x + WALK / 2 + 1, k.y0 + INNER + 1, k.x0 + B - INNER - 1, k.y0 + plaza[1] - 1)
    k.b.scatter("tree", lawn, max(2, int(B * B / 1200)), 2.5)
    k.b.scatter("picnic table", lawn, 1, 1.5)
    k.visit(
        (walk_x, PATH),
        (mid, y0 - 2.0),
        (walk_x, PATH),
        (B - PATH, PATH),
        (B - PATH, B - PATH),
        (mid, B - PATH),
        (mid, pad[1] + 4.0),
        (mid, B - PATH),
    )
    k.b.region(
        k.name("entrance"), "building entrance with bicycle racks and benches", k.rect(plaza[0], plaza[1], plaza[2], y0)
    )
    k.b.region(k.name("service_area"), "service area behind the building with dumpsters", k.rect(*pad))
    k.b.region(
        k.name("front_lawn"),
        "open lawn between the sidewalk and the building entrance",
        k.rect(walk_x + WALK / 2, INNER, B - INNER, plaza[1]),
    )
    street_furniture(k, [("N", mid, 10.0)])


def park_block(k: Block) -> None:
    B = k.B
    perimeter(k)
    cx, cy = B / 2, 0.55 * B
    rx, ry = 0.17 * B, 0.12 * B
    gap = 5.0
    trail_x, trail_y = rx + gap, ry + gap
    ellipse = lambda a, b: shp_scale(Point(k.x0 + cx, k.y0 + cy).buffer(1.0, 64), a, b)  # noqa: E731
    k.b.paint(ellipse(trail_x + 1.25, trail_y + 1.25).difference(ellipse(trail_x - 1.25, trail_y - 1.25)), "dirt")
    k.b.paint(ellipse(rx, ry), "water")
    k.paint(cx - 1.25, INNER, cx + 1.25, cy - trail_y, "dirt")
    k.paint(INNER, cy - 1.25, cx - trail_x, cy + 1.25, "dirt")
    ang = np.linspace(0, 2 * np.pi, 33)
    ring = [(cx + trail_x * np.cos(a), cy + trail_y * np.sin(a)) for a in ang]
    k.walkway(*ring)
    k.walkway((cx, PATH), (cx, cy - trail_y))
    k.walkway((PATH, cy), (cx - trail_x, cy))
    for a in (0.6, 2.3, 3.9):
        bx, by = cx + (rx + 2.3) * np.cos(a), cy + (ry + 2.3) * np.sin(a)
        k.add("bench", bx, by, float(np.arctan2(by - cy, bx - cx) + np.pi / 2))
    lawn = k.rect(INNER + 1, INNER + 1, B - INNER - 1, B - INNER - 1).difference(ellipse(trail_x + 3.0, trail_y + 3.0))
    k.b.scatter("picnic table", lawn, 3 + int(B / 40), 1.6)
    k.b.scatter("trash can", lawn, 2, 0.6)
    k.b.scatter("tree", lawn, int(B * B / 350), 2.5)
    k.visit((PATH, cy), (cx - trail_x, cy), (cx, cy + trail_y), (cx + trail_x, cy), (cx, cy - trail_y), (cx, PATH))
    k.b.region(
        k.name("park"),
        "park with a pond, a dirt trail and picnic tables on the grass",
        k.rect(INNER, INNER, B - INNER, B - INNER),
    )
    street_furniture(k, [])


BLOCKS = {"parking": parking_block, "mall": mall_block, "building": building_block, "park": park_block}


# ---------------------------------------------------------------------------------------- grid
def grid_layout(
    b: WorldBuilder,
    n: int,
    block: float,
    kinds: list[str],
    row_stride: int | None = None,
    full_tours: int | None = None,
) -> None:
    """n x n blocks of side `block` between roads; kinds[j * n + i] for block (i, j).

    The robot's tour: with `row_stride` None, every block's own tour in serpentine block order.
    Otherwise it drives the sidewalks along every `row_stride`-th east-west road in a serpentine and
    takes the own tour of `full_tours` blocks beside them (one of each kind first, then spread out).
    """
    # In this order: the builder's random numbers are drawn as the blocks and objects are added.
    blocks, tours = _lay_blocks(b, n, block, kinds)
    if row_stride is None:
        for j in range(n):
            for i in range(n):
                b.waypoints.extend(tours[(i if j % 2 == 0 else n - 1 - i, j)])
    else:
        _road_tour(b, blocks, tours, n, block, kinds, row_stride, full_tours)
    _crossings(b, blocks, block)
    _intersections(b, n, block + ROAD)
    _bus_stop(b, blocks[(0, 0)], block)


def _lay_blocks(
    b: WorldBuilder, n: int, block: float, kinds: list[str]
) -> tuple[dict[tuple[int, int], Block], dict[tuple[int, int], list]]:
    """Roads everywhere, then each block (i, j) of its kind: the blocks and each one's own tour
    (its waypoints, taken off the builder's route to be ordered by the caller)."""
    pitch = block + ROAD
    b.paint(box(b.extent[0], b.extent[1], b.extent[2], b.extent[3]), "asphalt")
    blocks = {}
    for j in range(n):
        for i in range(n):
            x0, y0 = ROAD + i * pitch, ROAD + j * pitch
            b.paint(box(x0, y0, x0 + block, y0 + block), "grass")
            blocks[(i, j)] = Block(b, x0, y0, block, (i, j))
    tours = {}
    for ij, k in blocks.items():
        start = len(b.waypoints)
        BLOCKS[kinds[ij[1] * n + ij[0]]](k)
        tours[ij] = b.waypoints[start:]
        del b.waypoints[start:]
    return blocks, tours


def _road_tour(
    b: WorldBuilder,
    blocks: dict[tuple[int, int], Block],
    tours: dict[tuple[int, int], list],
    n: int,
    block: float,
    kinds: list[str],
    row_stride: int,
    full_tours: int | None,
) -> None:
    """The route along the sidewalks of every `row_stride`-th east-west road, in a serpentine,
    with the own tours of the blocks `_choose_tours` picks beside them."""
    legs = []  # (block beside the road, its corners in travel order)
    for leg, r in enumerate(range(1, n, row_stride)):
        cols = range(n) if leg % 2 == 0 else range(n - 1, -1, -1)
        for i in cols:
            k = blocks[(i, r - 1)]
            ends = [k.p(PATH, block - PATH), k.p(block - PATH, block - PATH)]
            legs.append(((i, r - 1), ends if leg % 2 == 0 else ends[::-1]))
    chosen = _choose_tours([ij for ij, _ in legs], kinds, n, full_tours)
    for ij, ends in legs:
        b.waypoints.append(ends[0])
        if ij in chosen:
            b.waypoints.extend(tours[ij])
        b.waypoints.append(ends[1])


def _crossings(b: WorldBuilder, blocks: dict[tuple[int, int], Block], block: float) -> None:
    """Crosswalks between neighbouring blocks at both ends of their shared road."""
    for (i, j), k in blocks.items():
        for di, dj in ((1, 0), (0, 1)):
            if (i + di, j + dj) not in blocks:
                continue
            for end in (PATH, block - PATH):
                if di:  # crossing the north-south road east of block (i, j)
                    a, c = k.p(block - PATH, end), (k.x0 + block + ROAD + PATH, k.y0 + end)
                    b.paint(box(a[0], a[1] - WALK / 2, c[0], a[1] + WALK / 2), "sidewalk")
                    b.paint(box(k.x0 + block, a[1] - WALK / 2, k.x0 + block + ROAD, a[1] + WALK / 2), "asphalt")
                    b.add("crosswalk", k.x0 + block + ROAD / 2, a[1], 0.0, conform=True, length=ROAD - 0.6)
                else:
                    a, c = k.p(end, block - PATH), (k.x0 + end, k.y0 + block + ROAD + PATH)
                    b.paint(box(a[0] - WALK / 2, a[1], a[0] + WALK / 2, c[1]), "sidewalk")
                    b.paint(box(a[0] - WALK / 2, k.y0 + block, a[0] + WALK / 2, k.y0 + block + ROAD), "asphalt")
                    b.add("crosswalk", a[0], k.y0 + block + ROAD / 2, np.pi / 2, conform=True, length=ROAD - 0.6)
                b.walkway(a, c)


def _intersections(b: WorldBuilder, n: int, pitch: float) -> None:
    """Stop lights and a street sign at every inner intersection, and the middle one as a region."""
    for j in range(1, n):
        for i in range(1, n):
            cx, cy = i * pitch + ROAD / 2, j * pitch + ROAD / 2
            for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                u, v = cx + sx * (ROAD / 2 + VERGE / 2), cy + sy * (ROAD / 2 + VERGE / 2)
                b.add("stop light", u, v, float(np.arctan2(-sy, -sx)))
            b.add("street sign", cx - ROAD / 2 - VERGE / 2, cy + ROAD / 2 + 6.5, 0.0)
    if n >= 2:
        cx = cy = (n // 2) * pitch + ROAD / 2
        half = ROAD / 2 + INNER
        b.region(
            "intersection",
            "road intersection with crosswalks and stop lights",
            [(cx - half, cy - half), (cx + half, cy - half), (cx + half, cy + half), (cx - half, cy + half)],
        )


def _bus_stop(b: WorldBuilder, k: Block, block: float) -> None:
    """A bus stop just inside the south sidewalk of block `k`, open toward the road."""
    for du in (0.25, 0.75, 0.4, 0.6):
        x, y = k.p(du * block, INNER + 1.0)
        if b.is_free(x, y, 2.0):
            b.add("bus shelter", x, y, np.pi)
            break


def _choose_tours(
    candidates: list[tuple[int, int]], kinds: list[str], n: int, count: int | None
) -> set[tuple[int, int]]:
    """Blocks (in route order) that get their own tour: the first of each kind, then evenly spread."""
    if count is None:
        return set(candidates)
    chosen: list[tuple[int, int]] = []
    for kind in BLOCK_KINDS:
        first = next((ij for ij in candidates if kinds[ij[1] * n + ij[0]] == kind), None)
        if first is not None and len(chosen) < count:
            chosen.append(first)
    rest = [ij for ij in candidates if ij not in chosen]
    extra = count - len(chosen)
    if extra > 0 and rest:
        chosen += [rest[int(i)] for i in np.linspace(0, len(rest) - 1, min(extra, len(rest)))]
    return set(chosen)


def tiny_layout(b: WorldBuilder) -> None:
    """A 60 m x 60 m site: a parking lot, a sidewalk, a building with an entrance plaza, a bicycle
    rack, and a service lane with a dumpster behind the building."""
    rng = b.rng
    R = lambda x0, y0, x1, y1: box(x0, y0, x1, y1)  # noqa: E731
    b.paint(R(6, 3, 54, 21), "asphalt")
    b.paint(R(0, 21, 60, 24), "sidewalk")
    b.paint(R(25, 24, 35, 34.95), "sidewalk")
    b.paint(R(10, 29.5, 25, 32.5), "sidewalk")
    b.paint(R(10, 29.5, 13, 52), "sidewalk")
    b.paint(R(10, 49, 48, 58), "asphalt")
    b.paint(R(50, 30, 56, 36), "dirt")
    for v, yaw in ((5.5, np.pi / 2), (18.5, -np.pi / 2)):
        for u in np.arange(11.0, 50.0, 2.8):
            if rng.random() < 0.6:
                b.add("car", u, v, yaw + rng.normal(0, 0.03))
    b.add("building", 30.0, 42.0, 0.0, length=24.0, depth=12.0, height=9.0)
    b.add("stairs", 30.0, 35.45, 0.0, width=4.0)
    b.add("bicycle rack", 33.6, 29.0, np.pi / 2, hoops=4)
    for hoop in (0, 2, 3):
        b.add("bicycle", 33.6, 29.0 + (hoop - 1.5) * 0.8, 0.0)
    b.add("bench", 26.2, 27.0, -np.pi / 2)
    b.add("trash can", 26.2, 25.2)
    b.add("mailbox", 36.0, 25.0)
    b.add("dumpster", 32.0, 50.0, 0.0)
    b.add("street light", 15.0, 25.0, -np.pi / 2)
    b.add("street light", 47.0, 25.0, -np.pi / 2)
    b.add("fire hydrant", 57.0, 25.0)
    b.add("bollard", 4.5, 20.0)
    b.add("picnic table", 45.0, 30.0, 0.3)
    for x, y in ((20.0, 27.0), (41.0, 33.0), (7.0, 40.0), (53.0, 44.0)):
        b.add("tree", x, y)
    b.walkway((53, 12), (7, 12), (7, 22.5), (30, 22.5), (30, 31), (11.5, 31), (11.5, 54), (42, 54))
    b.visit((53, 12), (42, 54))
    b.region("parking_lot", "parking lot with rows of parked cars", [(6, 3), (54, 3), (54, 21), (6, 21)])
    b.region("entrance", "building entrance with a bicycle rack", [(25, 24), (35, 24), (35, 36), (25, 36)])
    b.region(
        "service_lane", "service lane behind the building with a dumpster", [(10, 49), (48, 49), (48, 58), (10, 58)]
    )
