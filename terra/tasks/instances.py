"""Separating adjacent instances of one class that DBSCAN joined into one cluster.

Two bicycle racks end to end, or benches side by side, stand closer than DBSCAN's eps, so their
points form one cluster. Such a cluster is elongated, and its footprint has a gap between the
instances that is wider than the spacing of its own points. A cluster whose footprint is at least
`min_length` metres long and `min_aspect` times longer than wide is split into the connected parts
of its xy points at a link distance of `gap_factor` times their median nearest-neighbour spacing
(the map's sampling, about one voxel). Parts with fewer than `min_share` of the cluster's points
or less than `min_height` metres tall (a stray bit of a bicycle, a mask bleeding onto the ground)
go back to the nearest large part, so only substantial, standing instances separate. Only points
standing above the ground are linked: at ground level one voxel layer (a rack's base bar, the
pavement a mask bled onto) runs through the gap between two instances.

Points are (n, 3) metres in the map frame.
"""

from __future__ import annotations

import numpy as np


def footprint_extent(xy: np.ndarray) -> tuple[float, float]:
    """(length, width) in metres of xy points (n, 2) along and across their direction of largest
    spread."""
    centred = xy - xy.mean(axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    along, across = centred @ vectors[:, -1], centred @ vectors[:, 0]
    return float(np.ptp(along)), float(np.ptp(across))


def split_instances(
    points: np.ndarray,
    min_length: float = 3.0,
    min_aspect: float = 1.8,
    gap_factor: float = 2.0,
    min_share: float = 0.3,
    min_height: float = 0.25,
    ground: float | None = None,
    lift: float = 0.15,
    min_spacing: float = 0.0,
) -> list[np.ndarray]:
    """Row-index arrays of the instances in one cluster's points (n, 3): the whole cluster, or its
    parts (see the module docstring), ordered by their lowest row.

    ground: metres (None = the cluster's lowest point); only points `lift` above it are linked,
    the others join the nearest part. min_spacing: metres, the least spacing (the map's voxel
    size: centroids of neighbouring voxels of one thin part lie much closer than a voxel)."""
    # SciPy's spatial and graph modules cost a cold query time: imported only when objects are split.
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  (compiled, no stub)

    points = np.asarray(points, dtype=np.float64)
    whole = [np.arange(len(points))]
    if len(points) < 8:
        return whole
    base = float(points[:, 2].min()) if ground is None else float(ground)
    standing = np.flatnonzero(points[:, 2] >= base + lift)
    if len(standing) < 8:
        standing = np.arange(len(points))
    xy = points[standing, :2]
    length, width = footprint_extent(xy)
    if length < min_length or length < min_aspect * width:
        return whole
    columns = np.unique(np.round(xy, 3), axis=0)  # points stacked up a pole share one xy
    if len(columns) < 2:
        return whole
    spacing = max(float(np.median(cKDTree(columns).query(columns, k=2)[0][:, 1])), min_spacing)
    pairs = cKDTree(xy).query_pairs(gap_factor * spacing * (1 + 1e-9), output_type="ndarray")  # <= rounded up
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(xy), len(xy)))
    n_parts, part = connected_components(graph, directed=False)
    sizes = np.bincount(part, minlength=n_parts)
    z = points[standing, 2]
    z_lo = np.full(n_parts, np.inf)
    z_hi = np.full(n_parts, -np.inf)
    np.minimum.at(z_lo, part, z)
    np.maximum.at(z_hi, part, z)
    large = np.flatnonzero(
        (sizes >= min_share * len(xy)) & (z_hi - (base if ground is not None else z_lo) >= min_height)
    )
    if len(large) < 2:
        return whole
    # Every other point (small parts, and what lies low) joins the large part with the nearest point.
    in_large = np.isin(part, large)
    _, nearest = cKDTree(xy[in_large]).query(points[:, :2])
    owner = part[in_large][nearest]
    groups = [np.flatnonzero(owner == p) for p in large]
    return sorted(groups, key=lambda g: int(g[0]))
