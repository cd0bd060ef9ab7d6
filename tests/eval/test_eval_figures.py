"""Figures: rasters colour the right cells, every report figure writes a valid, reproducible PNG."""

import dataclasses

import numpy as np
import pytest
from PIL import Image

from terra.datasets.ground_truth import GroundTruth, NamedRegion, ObjectBox, TerrainRaster
from terra.eval.metrics.boxes import BoxSet
from terra.graph.scene_graph import Places, RegionLevel, SceneGraph
from terra.viz import figures
from terra.viz.raster import rasterize_points, terrain_points_image, terrain_raster_image
from terra.viz.style import OTHER_COLOUR, terrain_colour

TERRAIN = ["sidewalk", "grass", "asphalt"]


def grid_graph() -> SceneGraph:
    """A 6 x 5 grid of places 4 m apart, terrain by column band, two region levels."""
    xs, ys = np.meshgrid(np.arange(6) * 4.0, np.arange(5) * 4.0)
    pos = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1)
    idx = np.arange(len(pos)).reshape(xs.shape)
    edges = np.concatenate(
        [np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1), np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1)]
    )
    terrain = (pos[:, 0] // 8).astype(np.int64)
    level1 = terrain.copy()
    level2 = np.array([0, 0, 1])
    regions = [
        RegionLevel(1, np.stack([pos[level1 == r].mean(0) for r in range(3)]), np.zeros((3, 3), np.float32), level1),
        RegionLevel(2, np.array([[4.0, 8, 0], [18, 8, 0]]), np.zeros((2, 3), np.float32), level2),
    ]
    places = Places(pos, terrain, np.ones(len(pos)), np.zeros((len(pos), 3), np.float32))
    kind = np.zeros(len(edges), np.int64)
    kind[0] = 2
    return SceneGraph(
        TERRAIN,
        np.eye(3, dtype=np.float32),
        places,
        edges,
        np.full(len(edges), 4.0),
        kind,
        regions,
        embedder="test",
        region_method="agglomerative",
    )


def ground_truth() -> GroundTruth:
    classes = np.array([[1, 2, 3], [1, 9, 3]], np.int32)
    raster = TerrainRaster(
        classes,
        np.zeros((2, 3), np.float32),
        np.array([-1.0, -1.0]),
        10.0,
        {1: "sidewalk", 2: "grass", 3: "asphalt", 9: "building"},
    )
    objects = [ObjectBox(1, 9, "car", np.array([5.0, 5, 0.75]), np.array([4.0, 2, 1.5]), 0.3)]
    regions = [NamedRegion("lot", "Large parking lot", np.array([[0, 0], [10, 0], [10, 10], [0, 10.0]]))]
    return GroundTruth(objects, raster, regions)


def test_rasterize_keeps_the_highest_point_per_cell():
    pts = np.array([[0.1, 0.1, 0.0], [0.2, 0.3, 2.0], [0.25, 0.05, 1.0], [1.1, 0.1, 0.0]])
    colours = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]], float)
    img = rasterize_points(pts, colours, cell=0.5)
    assert img.rgba.shape == (1, 3, 4)
    assert img.rgba[0, 0].tolist() == [0, 1, 0, 1]  # z = 2 wins its cell
    assert img.rgba[0, 1, 3] == 0  # empty cell is transparent
    assert img.rgba[0, 2].tolist() == [1, 1, 0, 1]
    assert img.extent == pytest.approx((0.1, 1.6, 0.05, 0.55))


def test_terrain_images_use_the_terrain_palette():
    pts = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    img = terrain_points_image(pts, np.array([1, -1]), TERRAIN, cell=1.0)
    assert tuple(img.rgba[0, 0, :3]) == pytest.approx(terrain_colour("grass"))
    terrain = ground_truth().terrain
    assert terrain is not None
    raster = terrain_raster_image(terrain, TERRAIN)
    assert tuple(raster.rgba[0, 0, :3]) == pytest.approx(terrain_colour("sidewalk"))
    assert tuple(raster.rgba[0, 2, :3]) == pytest.approx(terrain_colour("asphalt"))
    from matplotlib.colors import to_rgb

    assert tuple(raster.rgba[1, 1, :3]) == pytest.approx(to_rgb(OTHER_COLOUR))  # building: not terrain
    assert raster.extent == (-1.0, 29.0, -1.0, 19.0)


def draw_every_figure(out):
    sg, gt = grid_graph(), ground_truth()
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(0, 20, 2000), rng.uniform(0, 16, 2000), rng.uniform(0, 1, 2000)]
    background = terrain_points_image(pts, (pts[:, 0] // 8).astype(int), TERRAIN)
    gt_boxes = BoxSet.from_objects(gt.objects)
    pred = BoxSet(np.array([[5.5, 5, 0.7]]), np.array([[3, 2, 1.4]]), np.array([0.1]))
    classes = (pts[:, 0] // 8).astype(int)
    return [
        figures.terrain_map_figure(out / "terrain.png", TERRAIN, pts, classes, gt),
        figures.places_figure(out / "places.png", sg, background),
        figures.region_levels_figure(out / "regions.png", sg, background),
        figures.boxes_figure(
            out / "boxes.png", gt_boxes, {"ms-avg": (pred, np.array([0]))}, ["Find the car"], np.array([0]), background
        ),
        figures.paths_figure(
            out / "paths.png",
            sg,
            0,
            29,
            [
                ("shortest", np.array([0, 7, 14, 21, 28, 29]), 24.0),
                ("prefer sidewalk", np.array([0, 6, 12, 18, 24, 25, 26, 27, 28, 29]), 36.0),
            ],
            "Get bike from the bicycle rack",
            background,
        ),
        figures.monitoring_figure(
            out / "monitor.png", sg, gt.regions, [np.array([0, 1, 6, 7])], "mix", background, scores=[(0.5, 0.25)]
        ),
        figures.memory_figure(
            out / "memory.png", {"map: points": 300_000, "graph: nodes and edges": 40_000, "other": 3000}, 2000.0
        ),
    ]


def test_every_figure_writes_a_valid_reproducible_png(tmp_path):
    first = draw_every_figure(tmp_path / "a")
    second = draw_every_figure(tmp_path / "b")
    for a, b in zip(first, second):
        with Image.open(a) as im:
            im.verify()
        with Image.open(a) as im:
            assert im.format == "PNG" and im.size[0] >= 400 and im.size[1] >= 300
            assert "Software" not in im.info
            # Not blank: a real drawing has many distinct colours.
            rgb = np.asarray(im.convert("RGB")).astype(np.int64)
            assert np.unique(rgb[..., 0] << 16 | rgb[..., 1] << 8 | rgb[..., 2]).size > 20
        assert a.read_bytes() == b.read_bytes(), a.name


def test_places_view_grows_to_hold_places_beyond_the_raster():
    from terra.viz.places import extent_with_places

    sg = grid_graph()  # places over x 0..20, y 0..16: the larger side is 20 m, so the margin is 0.6 m
    # A raster view covering only part of the grid grows to every place with the margin.
    assert extent_with_places((2.0, 10.0, 1.0, 30.0), sg) == pytest.approx((-0.6, 20.6, -0.6, 30.0))
    # A view that already holds every place is left as it is; no view stays None.
    assert extent_with_places((-5.0, 25.0, -5.0, 25.0), sg) == (-5.0, 25.0, -5.0, 25.0)
    assert extent_with_places(None, sg) is None


def block_graph(side: int, block: int) -> tuple[SceneGraph, np.ndarray]:
    """A side x side grid of places 1 m apart linked to their 4 neighbours, and a region id per
    place: square blocks of block x block places, numbered row by row."""
    xs, ys = np.meshgrid(np.arange(side, dtype=float), np.arange(side, dtype=float))
    pos = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1)
    idx = np.arange(len(pos)).reshape(xs.shape)
    edges = np.concatenate(
        [np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1), np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1)]
    )
    per_row = side // block
    region = (ys.ravel() // block * per_row + xs.ravel() // block).astype(np.int64)
    places = Places(pos, np.zeros(len(pos), np.int64), np.ones(len(pos)), np.zeros((len(pos), 3), np.float32))
    sg = SceneGraph(
        TERRAIN,
        np.eye(3, dtype=np.float32),
        places,
        edges,
        np.ones(len(edges)),
        np.zeros(len(edges), np.int64),
        [],
        embedder="test",
    )
    return sg, region


def test_regions_joined_by_a_place_edge_never_share_a_colour():
    """64 regions (more than the 40 colours): the 8 x 8 blocks of a grid. Every edge between two
    blocks must join two colours; the shuffle of a palette gave some neighbours one colour."""
    from terra.viz.places import adjacent_region_colours

    sg, region = block_graph(32, 4)
    colours = adjacent_region_colours(sg, region)
    a, b = sg.place_edges[:, 0], sg.place_edges[:, 1]
    across = region[a] != region[b]
    assert across.sum() == 2 * 8 * 7 * 4  # 112 block borders, 4 edges each
    assert np.all(np.abs(colours[a[across]] - colours[b[across]]).sum(axis=1) > 0.05)
    # Places of one region share its colour.
    assert all(len(np.unique(colours[region == r], axis=0)) == 1 for r in range(64))


def test_a_level_of_few_regions_gets_distinct_hues():
    """Three regions side by side (a top level): three different hues, not shades of one blue."""
    import colorsys

    from terra.viz.places import adjacent_region_colours

    sg, region = block_graph(12, 4)
    region = region % 3  # three vertical bands of 4 columns
    colours = np.unique(adjacent_region_colours(sg, region), axis=0)
    hues = [colorsys.rgb_to_hsv(*c)[0] for c in colours]
    gaps = [min(abs(h - g), 1 - abs(h - g)) for i, h in enumerate(hues) for g in hues[i + 1 :]]
    assert len(colours) == 3 and min(gaps) > 0.1


def test_the_report_view_holds_every_place():
    """The shared view is the labelled raster's (-1..29 x -1..19 m here) grown to places beyond it."""
    from terra.eval.report_figures import shared_extent

    sg = grid_graph()
    raster = ground_truth().terrain
    assert raster is not None
    inside = shared_extent(raster, sg, np.zeros((1, 3)))
    assert inside == pytest.approx((-1.9, 29.9, -1.9, 19.9))  # the raster with 3 % of 30 m around it
    far = sg.places.position.copy()
    far[0, :2] = (-40.0, 60.0)  # a place built from far LiDAR returns
    moved = dataclasses.replace(sg, places=dataclasses.replace(sg.places, position=far))
    x0, x1, y0, y1 = shared_extent(raster, moved, np.zeros((1, 3)))
    xy = far[:, :2]
    assert x0 < xy[:, 0].min() and x1 >= 29.9 and y0 <= -1.9 and y1 > xy[:, 1].max()


def test_the_monitoring_figure_shows_the_bundles_own_hierarchy():
    """The demo and `terra monitor` rank the bundle's hierarchy (agglomerative by default): the
    figure shows that one, with its parameters, even where spectral scored better; without it, the
    best Terra hierarchy."""
    from terra.eval.metrics.regions import SetScores
    from terra.eval.regions import MonitoringRun
    from terra.eval.report_figures import _shown_hierarchy

    runs = {
        "spectral": MonitoringRun([np.arange(3)], [SetScores(3, 0, 0)], 0.1, parameters={"alpha": 0.3, "k": 1}),
        "agglomerative": MonitoringRun([np.arange(2)], [SetScores(1, 1, 2)], 0.1, parameters={"alpha": 0.3, "k": 5}),
        "aib": MonitoringRun([np.arange(1)], [SetScores(1, 0, 2)], 0.1),
    }
    assert _shown_hierarchy(runs, "agglomerative") == "agglomerative"
    assert _shown_hierarchy(runs, "") == "spectral"  # F1 1.0 against 0.4
    assert figures._with_parameters("agglomerative", runs["agglomerative"].parameters) == (
        "agglomerative, alpha 0.3, k 5"
    )


def test_the_navigation_figure_shows_the_case_where_the_preference_matters(tmp_path):
    """The task's two plans may coincide; the pair where preferring sidewalk changes the path is
    drawn as a second row, its paths magenta like the first row's."""
    from terra.viz.style import PATH_COLOUR

    sg = grid_graph()
    plans = [("shortest", np.array([5, 10, 15, 20]), 17.0), ("prefer sidewalk", np.array([5, 10, 15, 20]), 17.0)]
    case = figures.PathCase(
        "where preferring sidewalk changes the path",
        0,
        29,
        [
            ("shortest", np.array([0, 7, 14, 21, 28, 29]), 24.0),
            ("prefer sidewalk", np.array([0, 6, 12, 18, 24, 25, 26, 27, 28, 29]), 36.0),
        ],
        ["ground truth: grass 100 %", "ground truth: sidewalk 80 %"],
    )
    one = figures.paths_figure(tmp_path / "one.png", sg, 5, 20, plans, "Get bike", dpi=60)
    two = figures.paths_figure(tmp_path / "two.png", sg, 5, 20, plans, "Get bike", dpi=60, case=case)
    magenta = np.array([int(PATH_COLOUR[i : i + 2], 16) for i in (1, 3, 5)])

    def path_rows(png) -> np.ndarray:
        rgb = np.asarray(Image.open(png).convert("RGB")).astype(int)
        return np.flatnonzero((np.abs(rgb - magenta).sum(axis=2) < 30).any(axis=1))

    rows_one, rows_two = path_rows(one), path_rows(two)
    height = np.asarray(Image.open(two)).shape[0]
    assert np.asarray(Image.open(one)).shape[0] < 0.75 * height
    # Paths in both halves of the two-row figure; the one-row figure has them in one band only.
    assert rows_two.min() < height / 2 < rows_two.max() and len(rows_one) > 0


def test_a_method_repeating_anothers_boxes_is_named_as_such():
    """Fig. 4 draws every method's boxes; identical sets (3dsg = ms-avg on the demo) lie exactly
    on top of each other, so the legend says which repeats which."""
    from terra.viz.retrieval_figure import same_boxes

    a = BoxSet(np.array([[1.0, 2, 0.5], [5, 5, 0.5]]), np.ones((2, 3)), np.array([0.0, 0.3]))
    moved = BoxSet(np.array([[1.0, 2, 0.5], [5, 5.1, 0.5]]), np.ones((2, 3)), np.array([0.0, 0.3]))
    q = np.array([0, 1])
    predictions = {"ms-avg": (a, q), "ms-max": (moved, q), "3dsg": (a, q.copy())}
    assert same_boxes(predictions) == {"3dsg": "ms-avg"}
    assert same_boxes({"ms-avg": (a, q), "3dsg": (a, np.array([1, 0]))}) == {}  # other queries


def test_a_grid_over_another_grids_extent_has_its_shape():
    """The terrain figure lays the ground truth's grid over the map grid's (snapped) extent; a
    report view grown to the places has arbitrary edges, where rounding once added a cell
    ((217, 197) against (218, 198) on the small campus)."""
    from terra.viz.class_grid import ClassGrid

    rng = np.random.default_rng(0)
    for _ in range(2000):
        x0, y0 = rng.uniform(-50, 50, 2)
        w, h = rng.uniform(1, 300, 2)
        cell = float(rng.choice([0.2, 0.3, 0.4, 0.7, 1.0]))
        grid = ClassGrid.empty((x0, x0 + w, y0, y0 + h), cell, 3)
        assert grid.index.shape == (int(np.ceil(h / cell - 1e-6)), int(np.ceil(w / cell - 1e-6)))
        assert ClassGrid.empty(grid.extent, cell, 3).index.shape == grid.index.shape
