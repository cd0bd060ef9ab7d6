"""The scene graph as plain arrays: places, region levels, objects, and their edges.

Frames and units: every position is in the map frame, metres (z is the local ground height for
places). Embeddings are float32 unit vectors in the space of the map's embedder.
Layers follow spark_dsg: objects (2), places (3), regions (4, with levels 1..L above the places),
and an implicit root above the top region level.

Nodes follow spark_dsg's model too: each has a stable integer id (`id` arrays, int64, one per
node), which is its name (`p12`, NodeSymbol 'p' << 56 | 12) and survives rebuilds where its
ground did not change (terra.graph.ids); the arrays are views ordered by index, the position in
them, which the edges and parent links use. A graph built before ids existed has ids = indices.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import scipy.sparse as sp  # imported in the bodies that use it: lookups load the graph without SciPy

EDGE_GVD = 0  # along one terrain's GVD
# A link between GVDs: a dead end to the nearest place of another terrain, a curb gap's place to
# each side, a level link, or (LiDAR-only ground) a link across a line of steps.
EDGE_CROSS_TERRAIN = 1
EDGE_BRIDGE = 2  # joins otherwise disconnected components, with a penalty
EDGE_LEVEL_ROUTE = 3  # one straight leg of a route over level ground between pieces (terra.graph.level_routes)
EDGE_KINDS = (EDGE_GVD, EDGE_CROSS_TERRAIN, EDGE_BRIDGE, EDGE_LEVEL_ROUTE)
# The ground geometry of a place edge (terra.graph.ground.edge_geometry), one column each: the
# largest step it crosses (m), its steepest rise and fall from its first place to its second
# (degrees), the longest stretch of it over ground the map never observed (m), the steepest slope
# of the ground across it (degrees, either side: a wheel on the low side tips the robot).
EDGE_GEOMETRY_COLUMNS = ("step_m", "rise_deg", "fall_deg", "unobserved_m", "cross_deg")
# The columns of an edge's geometry read from its first place to its second, and from its second
# to its first: rise and fall swap.
EDGE_GEOMETRY_FORWARDS = list(range(len(EDGE_GEOMETRY_COLUMNS)))
EDGE_GEOMETRY_REVERSED = [0, 2, 1, 3, 4]
MAX_NODE_ID = (1 << 56) - 1  # a NodeSymbol keeps 56 bits for the index


def level_char(level: int) -> str:
    """The NodeSymbol character of region level `level` (1-based): 'R', 'S', ..."""
    return chr(ord("R") + level - 1)


def _no_ids() -> np.ndarray:
    return np.zeros(0, dtype=np.int64)


def node_ids(ids: np.ndarray, count: int, what: str) -> np.ndarray:
    """`ids` as (count,) int64, or 0..count-1 when none are given (an empty array); ValueError
    unless they are distinct and within 0..MAX_NODE_ID."""
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    if len(ids) == 0 and count:
        return np.arange(count, dtype=np.int64)
    if len(ids) != count:
        raise ValueError(f"{what}: {len(ids)} ids for {count} nodes")
    if count and (ids.min() < 0 or ids.max() > MAX_NODE_ID or len(np.unique(ids)) != count):
        raise ValueError(f"{what}: ids must be distinct integers 0..{MAX_NODE_ID}")
    return ids


def index_of(ids: np.ndarray) -> dict[int, int]:
    """id -> index for one layer's `ids`."""
    return {int(node_id): index for index, node_id in enumerate(ids.tolist())}


@dataclass
class Places:
    """Terrain-aware place nodes.

    position: (P, 3) metres, map frame; z from the local ground. terrain: (P,) index into
    SceneGraph.terrain_classes. clearance: (P,) metres to the nearest cell not of this terrain.
    embedding: (P, D) image embedding (mean of whole-image embeddings of images that saw the place).
    id: (P,) stable ids (default 0..P-1).
    room: (P,) metres to the nearest obstacle (terra.graph.room, at most ROOM_REACH), what robot
    widths are checked against; NaN where unknown (a bundle written before it was recorded).
    """

    position: np.ndarray
    terrain: np.ndarray
    clearance: np.ndarray
    embedding: np.ndarray
    id: np.ndarray = field(default_factory=_no_ids)
    room: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.id = node_ids(self.id, len(self), "places")
        if self.room is None:
            self.room = np.full(len(self), np.nan)
        elif len(self.room) != len(self):
            raise ValueError(f"places: {len(self.room)} room values for {len(self)} places")

    def __len__(self) -> int:
        return int(self.position.shape[0])


@dataclass
class RegionLevel:
    """One level of regions. Level 1 groups places, level k groups the regions of level k-1.

    position: (R, 3) centroid of members, metres. embedding: (R, D) normalised mean of children.
    parent_of_child: (C,) index of this level's region containing each node of the level below.
    id: (R,) stable ids (default 0..R-1).
    """

    level: int
    position: np.ndarray
    embedding: np.ndarray
    parent_of_child: np.ndarray
    id: np.ndarray = field(default_factory=_no_ids)

    def __post_init__(self) -> None:
        self.id = node_ids(self.id, len(self), f"region level {self.level}")

    @property
    def char(self) -> str:
        """The NodeSymbol character of this level: 'R' for level 1, 'S' for 2, ..."""
        return level_char(self.level)

    def __len__(self) -> int:
        return int(self.position.shape[0])


@dataclass
class Objects:
    """Retrieved objects: gravity-aligned oriented boxes linked to their nearest place.

    center, size: (O, 3) metres (size along the box axes before yaw). yaw: (O,) radians about +z.
    score: (O,) cosine score for `label`. place: (O,) index of the nearest place.
    id: (O,) stable ids (default 0..O-1).
    """

    center: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    size: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    yaw: np.ndarray = field(default_factory=lambda: np.zeros(0))
    label: list[str] = field(default_factory=list)
    score: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.float32))
    point_count: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    place: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    id: np.ndarray = field(default_factory=_no_ids)

    def __post_init__(self) -> None:
        self.id = node_ids(self.id, len(self), "objects")

    def __len__(self) -> int:
        return len(self.label)


@dataclass
class SceneGraph:
    """Terra's hierarchical terrain-aware scene graph.

    place_edges: (E, 2) place index pairs (i < j); place_edge_weight: (E,) traversal cost in metres
    (bridges carry their penalty); place_edge_kind: (E,) EDGE_* constants.
    place_edge_geometry: (E, 5) float32 ground geometry of each edge (terra.graph.ground,
    EDGE_GEOMETRY_COLUMNS): the largest step it crosses (m), its steepest rise and fall going from
    place_edges[:, 0] to place_edges[:, 1] (degrees), the longest stretch of it over unobserved
    ground (m) and the steepest slope across it (degrees) (the last two NaN, unknown, in a bundle
    written before they were recorded); (0, 5) when the graph was built without ground layers.
    Robot profiles read it at planning time (terra.tasks.robot); the graph is the same for every
    robot.
    terrain_embeddings: (T, D) text embedding of each terrain class name.
    next_id: the next free id per NodeSymbol character ('p' places, 'R', 'S', ... region levels,
    'O' objects): ids at or above it were never given; see `next_ids`.
    """

    terrain_classes: list[str]
    terrain_embeddings: np.ndarray
    places: Places
    place_edges: np.ndarray
    place_edge_weight: np.ndarray
    place_edge_kind: np.ndarray
    regions: list[RegionLevel] = field(default_factory=list)
    objects: Objects = field(default_factory=Objects)
    embedder: str = ""
    region_method: str = ""
    next_id: dict[str, int] = field(default_factory=dict)
    place_edge_geometry: np.ndarray = field(
        default_factory=lambda: np.zeros((0, len(EDGE_GEOMETRY_COLUMNS)), dtype=np.float32)
    )

    @property
    def has_edge_geometry(self) -> bool:
        """Whether every place edge carries its ground geometry."""
        return len(self.place_edges) > 0 and self.place_edge_geometry.shape == (
            len(self.place_edges),
            len(EDGE_GEOMETRY_COLUMNS),
        )

    def next_ids(self) -> dict[str, int]:
        """The next free id of every layer: the recorded one, raised above the ids in use."""
        layers = {"p": self.places.id, "O": self.objects.id} | {level.char: level.id for level in self.regions}
        out = dict(self.next_id)
        for char, ids in layers.items():
            out[char] = max(out.get(char, 0), int(ids.max()) + 1 if len(ids) else 0)
        return out

    def place_adjacency(self) -> sp.csr_matrix:
        """Symmetric (P, P) sparse matrix of place edge weights."""
        import scipy.sparse as sp  # here: monitoring and lookups load the graph without SciPy

        n = len(self.places)
        i, j = self.place_edges[:, 0], self.place_edges[:, 1]
        w = self.place_edge_weight.astype(np.float64)
        adjacency = sp.coo_matrix(
            (np.concatenate([w, w]), (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(n, n)
        ).tocsr()
        return adjacency  # pyright: ignore[reportReturnType]  # scipy infers csr_array for coo_matrix.tocsr()

    def place_region(self, level: int) -> np.ndarray:
        """(P,) index of the region at `level` (1-based) containing each place."""
        assignment = np.arange(len(self.places))
        for region_level in self.regions[:level]:
            assignment = region_level.parent_of_child[assignment]
        return assignment

    def region_places(self, level: int, region: int) -> np.ndarray:
        """Indices of the places inside region `region` of `level`."""
        return np.flatnonzero(self.place_region(level) == region)
