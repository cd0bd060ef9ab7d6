"""What `terra changes` adds to the changes found (terra/mapping/changes.py) for a reader: the class name of
each changed object and a summary per region of the scene graph (`report_changes`: what the command line,
the service and the viewer answer). It reads the scene graph, one stage after the map.

Names: a bank entry is an embedding (the text embedding of a class name with the `labels` backend, an image
embedding with a camera model), so an entry is named by the map's object class (map/meta.json) whose name,
embedded with the map's own text embedder, lies nearest it, when that cosine is at least `NAME_COSINE`.
Regions: each change is placed in the finest region (level 1) of the place nearest it (x-y metres, map
frame); the region is named by its node symbol (`R12`), as `terra info` and the graph files name it.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.mapping.changes import ChangeSettings, ChangesResult, RegionChanges, detect_changes
from terra.npy import ArraySpec

NAME_COSINE = 0.5  # below this an entry resembles no class name enough to be called by it


def entry_names(bundle: Bundle, entries: set[int]) -> dict[int, str]:
    """Class name per bank entry of `entries`; {} where the map records no object classes or no embedder, or
    its embedder cannot be loaded here (the report then gives entry numbers only)."""
    from terra.perception.text import normalize_rows, resolve_embedder
    from terra.schemas import MapMeta

    info, embedder_info = bundle.model.components.map, bundle.model.embedder
    if not entries or info is None or embedder_info is None or not bundle.has("map/meta.json"):
        return {}
    names = [c.name for c in bundle.document("map/meta.json", MapMeta).classes if c.id != 0 and not c.terrain]
    if not names:
        return {}
    try:
        embedder = resolve_embedder(embedder_info.name, embedder_info.dim)
    except (TerraError, ImportError, OSError):  # a model not installed here: numbers, not a failed report
        return {}
    bank = bundle.array("map/bank", ArraySpec(("float16", "float32"), (int(info.bank or 0), embedder_info.dim)))
    vectors = normalize_rows(np.asarray(embedder.embed_text(names), np.float32))
    wanted = sorted(e for e in entries if e >= 0)  # -1: an object only the LiDAR saw, no entry to name
    if not wanted:
        return {}
    cosine = normalize_rows(np.asarray(bank, np.float32)[wanted]) @ vectors.T
    best = cosine.argmax(axis=1)
    return {e: names[int(b)] for e, b, c in zip(wanted, best, cosine.max(axis=1)) if c >= NAME_COSINE}


def graph_regions(bundle: Bundle, xy: np.ndarray) -> list[str] | None:
    """The level-1 region (node symbol, `R12`) of the place nearest each of `xy` (M, 2) metres, map frame;
    None when the bundle has no scene graph or its graph has no regions."""
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled module

    from terra.graph.storage import load_scene_graph

    if bundle.model.components.graph is None:
        return None
    graph = load_scene_graph(bundle)
    if not graph.regions or len(graph.places) == 0:
        return None
    level = graph.regions[0]
    if xy.shape[0] == 0:
        return []
    _, nearest = cKDTree(graph.places.position[:, :2]).query(np.asarray(xy, np.float64).reshape(-1, 2))
    region = level.parent_of_child[np.asarray(nearest, np.int64)]
    return [f"{level.char}{int(level.id[r])}" for r in region]


def summarise_regions(
    object_regions: list[str], kinds: list[str], terrain_regions: list[str], pairs: list[str], areas: np.ndarray
) -> list[RegionChanges]:
    """Per region (name order): object changes of `kinds` (one per entry of `object_regions`) and terrain
    `areas` (m², one per cell of `terrain_regions`, its "before -> after" pair in `pairs`)."""
    out: dict[str, RegionChanges] = {}
    for region, kind in zip(object_regions, kinds):
        row = out.setdefault(region, RegionChanges(region))
        setattr(row, kind, getattr(row, kind) + 1)
    for region, pair, area in zip(terrain_regions, pairs, np.asarray(areas, np.float64)):
        row = out.setdefault(region, RegionChanges(region))
        row.terrain_m2[pair] = row.terrain_m2.get(pair, 0.0) + float(area)
    return [out[k] for k in sorted(out, key=lambda name: (len(name), name))]


def report_changes(path: Path, first: int, second: int, settings: ChangeSettings | None = None) -> ChangesResult:
    """`terra changes`: the changes from session `first` to `second` of the joined map in bundle `path`
    (terra.mapping.changes.detect_changes), each object named by its class and, with a scene graph, placed
    in its region, with the per-region summary."""
    return describe_changes(Bundle(path), detect_changes(path, first, second, settings))


def describe_changes(bundle: Bundle, result: ChangesResult) -> ChangesResult:
    """Name each changed object by its class and place it and the terrain cells in the graph's regions."""
    names = entry_names(bundle, {o.entry for o in result.objects})
    where = np.array([(o.after or o.before or (0.0, 0.0, 0.0))[:2] for o in result.objects]).reshape(-1, 2)
    regions = graph_regions(bundle, np.vstack([where, result.terrain_cells]))
    result.objects = [
        replace(o, name=names.get(o.entry), region=None if regions is None else regions[i])
        for i, o in enumerate(result.objects)
    ]
    if regions is not None:
        n = len(result.objects)
        areas = np.full(len(result.terrain_pairs), result.terrain_cell_area)
        kinds = [o.change for o in result.objects]
        result.regions = summarise_regions(regions[:n], kinds, regions[n:], result.terrain_pairs, areas)
    return result
