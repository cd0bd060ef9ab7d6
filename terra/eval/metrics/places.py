"""Places against the ground-truth terrain raster: do the places follow continuous terrain strips?

For every terrain class t, the ground-truth raster's cells of class t split into 8-connected
components (a sidewalk along a block, a path through a park). A place of terrain t whose xy lies
on a cell of class t belongs to that cell's component; places whose ground-truth cell has another
class are not counted (`off_terrain`). Two places of terrain t on one component should be joined
by a path in the places graph that uses only places of terrain t (so only edges between two
places of t): a route that exists on that terrain in the world exists in the graph.

`joined_share` is the share of such pairs that are joined: for a component whose n places fall
into graph components of sizes s_1..s_m (within the terrain-t subgraph), the pairs are
n (n - 1) / 2 and the joined ones sum_i s_i (s_i - 1) / 2.

Which ground counts: the issue asks for routes on strips "that the robot saw". Over the whole
raster, pairs are also joined in the world through ground no sensor observed (the far side of a
block, roads beyond the scan range); no map can know those routes (on the small preset, seed 1,
even ground-truth classes on every scanned point and places on sparsely scanned ground join only
0.91 of the raster's pairs, against 0.997 over the scanned ground). So the target is judged over
the ground the cameras labelled (`observed_cells` of the points with a terrain class: terrain
comes only from the cameras), and the whole raster is reported beside it.

The measure counts missing joins, not wrong ones: a map that labelled everything one class would
join every pair. `place_terrain_agreement` measures the other side, how many places sit on
ground of their own terrain.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy import ndimage
from scipy.sparse.csgraph import connected_components

from terra.datasets.ground_truth import TerrainRaster
from terra.graph.scene_graph import SceneGraph

EIGHT = np.ones((3, 3), dtype=bool)


def eight_components(mask: np.ndarray) -> np.ndarray:
    """(H, W) int32 labels of the 8-connected components of the bool raster `mask` (0 = not in it)."""
    found = ndimage.label(mask, structure=EIGHT)
    if not isinstance(found, tuple):  # without an `output` array, label returns (labels, count)
        raise TypeError("scipy.ndimage.label returned no label array")
    return np.asarray(found[0])


@dataclass
class TerrainConnectivity:
    """Pair counts of one terrain class (see the module docstring)."""

    places: int = 0
    off_terrain: int = 0
    pairs: int = 0
    joined: int = 0

    @property
    def share(self) -> float:
        return self.joined / self.pairs if self.pairs else 1.0


@dataclass
class PlaceConnectivity:
    """Same-terrain connectivity of a places graph, in total and per terrain name."""

    per_terrain: dict[str, TerrainConnectivity] = field(default_factory=dict)

    @property
    def pairs(self) -> int:
        return sum(t.pairs for t in self.per_terrain.values())

    @property
    def joined(self) -> int:
        return sum(t.joined for t in self.per_terrain.values())

    @property
    def joined_share(self) -> float:
        return self.joined / self.pairs if self.pairs else 1.0

    def to_json(self) -> dict:
        return {
            "pairs": self.pairs,
            "joined": self.joined,
            "joined_share": self.joined_share,
            "per_terrain": {k: {**asdict(v), "share": v.share} for k, v in sorted(self.per_terrain.items())},
        }


def joined_pairs(component: np.ndarray, graph_component: np.ndarray) -> tuple[int, int]:
    """(pairs, joined pairs) of items labelled by ground-truth `component` and by graph component
    (both (n,) integer labels): pairs share a ground-truth component, joined ones also a graph one."""

    def pair_count(labels: np.ndarray) -> int:
        if len(labels) == 0:
            return 0
        _, counts = np.unique(labels, axis=0, return_counts=True)
        return int((counts * (counts - 1) // 2).sum())

    component = np.asarray(component, dtype=np.int64)
    both = np.column_stack([component, np.asarray(graph_component, dtype=np.int64)])
    return pair_count(component[:, None]), pair_count(both)


def observed_cells(
    raster: TerrainRaster, points: np.ndarray, reach: float = 0.5, max_height: float = 0.3
) -> np.ndarray:
    """(H, W) bool: raster cells within `reach` metres (2-D) of a map point (N, 3, map frame)
    that lies at most `max_height` metres above the ground-truth ground there: the ground the
    robot's LiDAR saw."""
    points = np.asarray(points, dtype=np.float64)
    rows, cols, inside = raster.cell_of(points[:, :2])
    near_ground = inside & (np.abs(points[:, 2] - raster.ground_height[rows, cols]) <= max_height)
    seen = np.zeros(raster.classes.shape, dtype=bool)
    seen[rows[near_ground], cols[near_ground]] = True
    radius = int(np.ceil(reach / raster.resolution))
    yy, xx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    return ndimage.binary_dilation(seen, structure=(xx**2 + yy**2) * raster.resolution**2 <= reach**2)


def same_terrain_connectivity(
    graph: SceneGraph, raster: TerrainRaster, observed: np.ndarray | None = None
) -> PlaceConnectivity:
    """Connectivity of same-terrain places on each ground-truth terrain component (module doc).
    observed: (H, W) bool raster cells the robot saw (see `observed_cells`); components are then
    taken over the observed cells of each class only (None = the whole raster)."""
    legend_id = {name: cid for cid, name in raster.legend.items()}
    out = PlaceConnectivity()
    position = np.asarray(graph.places.position, dtype=np.float64)
    terrain = np.asarray(graph.places.terrain, dtype=np.int64)
    edges = np.asarray(graph.place_edges, dtype=np.int64).reshape(-1, 2)
    for t, name in enumerate(graph.terrain_classes):
        mine = np.flatnonzero(terrain == t)
        if mine.size == 0 or name not in legend_id:
            continue
        cells = raster.classes == legend_id[name]
        labels = eight_components(cells if observed is None else cells & observed)
        rows, cols, inside = raster.cell_of(position[mine, :2])
        component = np.where(inside, labels[rows, cols], 0)
        on = component > 0
        # Graph components of the terrain-t subgraph (edges between two places of t only).
        local = np.full(len(position), -1, dtype=np.int64)
        local[mine] = np.arange(mine.size)
        keep = (local[edges[:, 0]] >= 0) & (local[edges[:, 1]] >= 0)
        a, b = local[edges[keep, 0]], local[edges[keep, 1]]
        adjacency = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(mine.size, mine.size))
        _, graph_component = connected_components(adjacency, directed=False)
        pairs, joined = joined_pairs(component[on], graph_component[on])
        out.per_terrain[name] = TerrainConnectivity(int(mine.size), int((~on).sum()), pairs, joined)
    return out


@dataclass
class TerrainAgreement:
    """How many places sit on their own terrain in the ground truth: `places` on a labelled raster
    cell, `agreeing` on a cell of their terrain, `farther` per distance d (metres) the places more
    than d from any cell of their terrain (a misplaced boundary of d or less is not a wrong patch)."""

    places: int = 0
    agreeing: int = 0
    farther: dict[float, int] = field(default_factory=dict)

    @property
    def share(self) -> float:
        return self.agreeing / self.places if self.places else 1.0

    def to_json(self) -> dict:
        return {
            "places": self.places,
            "agreeing": self.agreeing,
            "share": self.share,
            "farther_than_m": {f"{d:g}": n for d, n in sorted(self.farther.items())},
        }


def place_terrain_agreement(
    graph: SceneGraph, raster: TerrainRaster, distances: tuple[float, ...] = (1.0, 4.0)
) -> TerrainAgreement:
    """Places against the ground-truth class under them (see TerrainAgreement). Places outside
    the raster or on an unlabelled cell (class 0) are not counted; a terrain class the raster does
    not know counts as disagreeing everywhere."""
    legend_id = {name: cid for cid, name in raster.legend.items()}
    position = np.asarray(graph.places.position, dtype=np.float64)
    terrain = np.asarray(graph.places.terrain, dtype=np.int64)
    rows, cols, inside = raster.cell_of(position[:, :2])
    counted = inside & (raster.classes[rows, cols] != 0)
    out = TerrainAgreement(places=int(counted.sum()), farther={float(d): 0 for d in distances})
    for t, name in enumerate(graph.terrain_classes):
        mine = np.flatnonzero(counted & (terrain == t))
        if mine.size == 0:
            continue
        cid = legend_id.get(name)
        if cid is None:
            for d in out.farther:
                out.farther[d] += int(mine.size)
            continue
        cells = raster.classes == cid
        out.agreeing += int(cells[rows[mine], cols[mine]].sum())
        if not cells.any():
            gap = np.full(cells.shape, np.inf)
        else:
            gap = np.asarray(ndimage.distance_transform_edt(~cells)) * raster.resolution
        for d in out.farther:
            out.farther[d] += int((gap[rows[mine], cols[mine]] > d).sum())
    return out
