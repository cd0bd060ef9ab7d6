"""Evaluation metrics against hand-worked examples."""

import numpy as np
import pytest

from terra.bundle import BundleWriter
from terra.datasets.ground_truth import TerrainRaster
from terra.eval.metrics.boxes import BoxSet, box_iou, iou_matrix
from terra.eval.metrics.memory import mapped_area, memory_summary
from terra.eval.metrics.navigation import path_length, path_terrain_lengths, terrain_shares
from terra.eval.metrics.regions import micro_scores, places_in_polygon, set_scores
from terra.eval.metrics.retrieval import evaluate_retrieval, greedy_match
from terra.eval.metrics.segmentation import confusion_matrix, segmentation_scores


def box(center, size, yaw=0.0):
    return BoxSet(np.array([center]), np.array([size]), np.array([yaw]))


def test_iou_of_cubes_offset_along_x_and_z_is_one_third():
    a = box([0, 0, 0], [1, 1, 1])
    # Overlap 0.5 m^3, union 1.5 m^3.
    assert box_iou(a, box([0.5, 0, 0], [1, 1, 1])) == pytest.approx(1 / 3)
    assert box_iou(a, box([0, 0, 0.5], [1, 1, 1])) == pytest.approx(1 / 3)
    assert box_iou(a, box([1.5, 0, 0], [1, 1, 1])) == 0.0
    assert box_iou(a, box([0, 0, 1.2], [1, 1, 1])) == 0.0


def test_iou_of_square_and_its_45_degree_rotation_is_one_over_sqrt2():
    # Footprint intersection is a regular octagon of area 8 (sqrt2 - 1) for side 2.
    a = box([0, 0, 0], [2, 2, 2])
    b = box([0, 0, 0], [2, 2, 2], np.pi / 4)
    assert box_iou(a, b) == pytest.approx(1 / np.sqrt(2))


def test_yaw_quarter_turn_swaps_footprint_axes():
    assert box_iou(box([3, 4, 1], [1, 2, 0.5], np.pi / 2), box([3, 4, 1], [2, 1, 0.5])) == pytest.approx(1.0)
    long_y = box([0, 0, 0], [2, 1, 1], np.pi / 2)
    inside = long_y.contains(np.array([[0, 0.9, 0], [0.9, 0, 0], [0, 0, 0.5]]))
    assert inside.tolist() == [[True, False, True]]


def test_iou_matrix_matches_pairwise_and_handles_empty():
    a = BoxSet(np.array([[0, 0, 0], [5, 0, 0]]), np.array([[1, 1, 1], [2, 2, 2]]), np.array([0, 0.3]))
    b = BoxSet(np.array([[0.5, 0, 0], [5, 0, 0]]), np.array([[1, 1, 1], [2, 2, 2]]), np.array([0, 0.3]))
    m = iou_matrix(a, b)
    assert m.shape == (2, 2)
    assert m[0, 0] == pytest.approx(1 / 3) and m[1, 1] == pytest.approx(1.0)
    assert m[0, 1] == 0 and m[1, 0] == 0
    assert iou_matrix(a, BoxSet.empty()).shape == (2, 0)


def test_greedy_match_takes_best_pair_first_not_the_optimal_assignment():
    p, g = greedy_match(np.array([[0.5, 0.4], [0.45, 0.0]]))
    assert p.tolist() == [0] and g.tolist() == [0]


def test_retrieval_metrics_on_a_hand_worked_scene():
    # Query 0 ("car"): two unit cubes; query 1 ("dumpster"): one 2 x 1 x 1 box.
    gt = [
        BoxSet(np.array([[0, 0, 0.5], [10, 0, 0.5]]), np.array([[1, 1, 1], [1, 1, 1]]), np.array([0, 0])),
        BoxSet(np.array([[20, 0, 0.5]]), np.array([[2, 1, 1]]), np.array([0])),
    ]
    pred = BoxSet(
        np.array([[0.25, 0, 0.5], [10.8, 0, 0.5], [30, 0, 0.5], [20, 0, 0.5], [20.4, 0, 0.5]]),
        np.array([[1, 1, 1], [3, 1, 1], [1, 1, 1], [4, 2, 2], [1, 1, 1]]),
        np.zeros(5),
    )
    scores = np.array([[0.9, 0.1], [0.85, 0.2], [0.5, 0.3], [0.1, 0.7], [0.0, 0.65]])
    assigned = np.array([0, 0, 0, 1, 1])
    s = evaluate_retrieval(pred, scores, assigned, gt)
    # Accuracy: P0-G0 IoU 0.6 strict; P1-G1 IoU 1/3, contains the GT centre only (relaxed);
    # P3-G2 IoU 2/16 strict (same centre). P2 is not among the top-2 for query 0.
    assert s.iou == pytest.approx((0.6 + 1 / 3 + 0.125) / 3)
    assert s.strict_accuracy == pytest.approx(2 / 3)
    assert s.relaxed_accuracy == pytest.approx(1.0)
    # Precision: query 0 keeps P0, P1 (>= 0.9 * 0.9); query 1 keeps P3, P4 (>= 0.9 * 0.7).
    # P4 (IoU 0.5) wins G2 over P3 (IoU 0.125) and is strict.
    assert s.num_precision_predictions == 4
    assert s.strict_precision == pytest.approx(2 / 4)
    assert s.relaxed_precision == pytest.approx(3 / 4)
    assert s.f1 == pytest.approx(2 * 0.75 * 1.0 / 1.75)
    assert [q["relaxed_hits"] for q in s.per_query] == [2, 1]


def test_retrieval_with_no_predictions_scores_zero():
    gt = [BoxSet(np.array([[0, 0, 0]]), np.array([[1, 1, 1]]), np.array([0]))]
    s = evaluate_retrieval(BoxSet.empty(), np.zeros((0, 1)), np.zeros(0), gt)
    assert (s.iou, s.relaxed_accuracy, s.relaxed_precision, s.f1) == (0, 0, 0, 0)
    assert s.num_gt == 1


def test_segmentation_scores_from_a_known_confusion_matrix():
    # Labels: 0 grass, 1 asphalt, 2 not terrain; -1 pixels are ignored.
    truth = np.array([0, 0, 0, 1, 1, 2, 2, 2, -1])
    pred = np.array([0, 0, 1, 1, 2, 2, 0, 2, 0])
    m = confusion_matrix(truth, pred, 3)
    assert m.tolist() == [[2, 1, 0], [0, 1, 1], [1, 0, 2]]
    s = segmentation_scores(m, ["grass", "asphalt"], seconds=2.0, images=5)
    # grass: tp 2, gt 3, pred 3 -> IoU 2/4, F1 4/6; asphalt: tp 1, gt 2, pred 2 -> IoU 1/3, F1 2/4.
    assert s.iou == pytest.approx([0.5, 1 / 3])
    assert s.miou == pytest.approx(5 / 12)
    assert s.fw_miou == pytest.approx(3 / 5 * 0.5 + 2 / 5 / 3)
    assert s.f1 == pytest.approx((2 / 3 + 0.5) / 2)
    assert s.fps == pytest.approx(2.5)


def test_segmentation_skips_classes_absent_from_truth_and_prediction():
    truth = np.array([[0, 0], [3, 3]])
    pred = np.array([[0, 0], [3, 1]])
    s = segmentation_scores(confusion_matrix(truth, pred, 4), ["grass", "asphalt", "dirt"])
    assert np.isnan(s.iou[2]) and s.iou[1] == 0.0 and s.iou[0] == 1.0
    assert s.miou == pytest.approx(0.5)  # dirt is skipped, asphalt (predicted once) counts as 0
    assert s.to_json()["iou"][2] is None


def test_region_precision_recall_on_a_square():
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]])
    xy = np.array([[1, 1], [5, 5], [9, 9], [11, 5], [-1, -1], [5, 12]])
    truth = places_in_polygon(xy, square)
    assert truth.tolist() == [0, 1, 2]
    # The polygon is closed: places on an edge or a corner belong to the region.
    assert places_in_polygon(np.array([[0.0, 5.0], [10.0, 10.0], [10.000001, 5.0]]), square).tolist() == [0, 1]
    s = set_scores([1, 2, 3, 4, 4], truth)
    assert (s.tp, s.fp, s.fn) == (2, 2, 1)
    assert (s.precision, s.recall, s.f1) == pytest.approx((0.5, 2 / 3, 4 / 7))
    total = micro_scores([s, set_scores([5], [5, 0])])
    assert (total.tp, total.fp, total.fn) == (3, 2, 2)
    assert total.precision == pytest.approx(0.6) and total.recall == pytest.approx(0.6)
    assert set_scores([], []).f1 == 0.0


def test_path_terrain_lengths_on_a_two_terrain_raster():
    classes = np.full((10, 10), 3, np.int32)
    classes[:, :5] = 2  # x < 5 m grass, x >= 5 m asphalt
    raster = TerrainRaster(classes, np.zeros((10, 10), np.float32), np.zeros(2), 1.0, {2: "grass", 3: "asphalt"})
    path = np.array([[1, 5.5, 0], [8, 5.5, 0], [8, 9.5, 0], [8, 12.5, 0]])
    assert path_length(path) == pytest.approx(14.0)
    lengths = path_terrain_lengths(path, raster, step=0.1)
    # grass x 1..5; asphalt x 5..8, then y 5.5..10 (raster ends at y = 10); off the raster y 10..12.5.
    assert lengths == pytest.approx({"grass": 4.0, "asphalt": 7.5, "outside": 2.5})
    assert terrain_shares(lengths)["grass"] == pytest.approx(4 / 14)


def test_mapped_area_and_memory_summary(tmp_path):
    pts = np.array([[0.1, 0.1, 5.0], [0.2, 0.3, -1.0], [1.0, 0.0, 0.0]])
    assert mapped_area(pts, cell=0.4) == pytest.approx(2 * 0.16)
    w = BundleWriter(tmp_path / "b")
    w.put_array("map/points", np.zeros((100, 3), np.float32))
    w.put_json("graph/g.json", {"a": 1})
    bundle = w.commit()
    m = memory_summary(bundle, area_m2=10.0)
    assert m["components_bytes"]["map"] == (tmp_path / "b/map/points.npy").stat().st_size
    assert m["components_bytes"]["graph"] == (tmp_path / "b/graph/g.json").stat().st_size
    assert m["total_bytes"] == sum(m["components_bytes"].values())
    assert m["bytes_per_m2"] == pytest.approx(m["total_bytes"] / 10.0)


# ---------------------------------------------------------------- issue 14: places, distances, timing


def test_same_terrain_connectivity_counts_pairs_per_ground_truth_component():
    """Two sidewalk strips (rows 0 and 4 of a 1 m raster, split by grass) and a sidewalk graph:
    places 0, 1, 2 on the first strip with 0-1 linked and 2 cut off; places 3, 4 on the second,
    linked only through a grass place (5), which a sidewalk-only path may not use; place 6 sits on
    grass although the graph calls it sidewalk (not counted)."""
    from terra.eval.metrics.places import observed_cells, same_terrain_connectivity
    from tests.tasks.test_tasks_synthetic import make_graph

    classes = np.full((5, 10), 1, dtype=np.int32)  # grass
    classes[0, :] = 0
    classes[4, :] = 0  # sidewalk strips along y = 0.5 and y = 4.5
    raster = TerrainRaster(classes, np.zeros((5, 10), np.float32), np.zeros(2), 1.0, {0: "sidewalk", 1: "grass"})
    position = [[0.5, 0.5], [3.5, 0.5], [8.5, 0.5], [1.5, 4.5], [7.5, 4.5], [4.5, 2.5], [2.5, 2.5]]
    terrain = [0, 0, 0, 0, 0, 1, 0]
    graph = make_graph(position, terrain, [[0, 1], [3, 5], [5, 4], [2, 6]])
    result = same_terrain_connectivity(graph, raster)
    side = result.per_terrain["sidewalk"]
    assert (side.places, side.off_terrain, side.pairs, side.joined) == (6, 1, 3 + 1, 1)
    assert result.per_terrain["grass"].pairs == 0 and result.joined_share == pytest.approx(1 / 4)
    # Only the first strip's left half seen (points at x 0.5 and 3.5, within 1 m), all of the second:
    # place 2 drops out, leaving the pairs 0-1 (joined) and 3-4 (not).
    points = np.array([[0.5, 0.5, 0.0], [3.5, 0.5, 0.0]] + [[x + 0.5, 4.5, 0.0] for x in range(10)])
    seen = observed_cells(raster, points, reach=1.0)
    assert seen[0, :5].all() and not seen[0, 6:].any() and seen[4].all()
    side = same_terrain_connectivity(graph, raster, seen).per_terrain["sidewalk"]
    assert (side.pairs, side.joined) == (2, 1)


def test_place_terrain_agreement_counts_wrong_places_by_distance_to_their_terrain():
    """A 1 m raster: sidewalk in columns 0-1, grass in 2-9, an unlabelled cell at (9, 4). Two
    sidewalk places on sidewalk; a sidewalk place on the first grass column (1 m from the sidewalk,
    cell centre to cell centre: a boundary drawn one cell off); one deep in the grass (column 8,
    7 m away); a grass place on grass; one place on the unlabelled cell and one outside the raster
    (neither counted)."""
    from terra.eval.metrics.places import place_terrain_agreement
    from tests.tasks.test_tasks_synthetic import make_graph

    classes = np.full((5, 10), 2, dtype=np.int32)
    classes[:, :2] = 1
    classes[4, 9] = 0
    raster = TerrainRaster(
        classes, np.zeros((5, 10), np.float32), np.zeros(2), 1.0, {0: "unlabeled", 1: "sidewalk", 2: "grass"}
    )
    position = [[0.5, 0.5], [1.5, 3.5], [2.5, 2.5], [8.5, 1.5], [5.5, 2.5], [9.5, 4.5], [20.0, 1.0]]
    terrain = [0, 0, 0, 0, 1, 1, 0]
    graph = make_graph(position, terrain, [], terrain_classes=["sidewalk", "grass"])
    result = place_terrain_agreement(graph, raster, distances=(1.0, 4.0))
    # Distances between cell centres: (2, 2) is 1 m from sidewalk column 1, (1, 8) is 7 m.
    assert (result.places, result.agreeing) == (5, 3)
    assert result.farther == {1.0: 1, 4.0: 1}
    assert result.share == pytest.approx(3 / 5)


def test_distance_to_path_and_iou_by_distance_band():
    from terra.eval.metrics.retrieval import accuracy_matches, distance_to_path, iou_by_distance

    path = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    d = distance_to_path(np.array([[5.0, 3.0], [12.0, 5.0], [-4.0, 3.0], [20.0, 20.0]]), path)
    np.testing.assert_allclose(d, [3.0, 2.0, 5.0, np.hypot(10.0, 10.0)])
    gt = [
        BoxSet(np.array([[5, 2, 0], [5, 30, 0]]), np.array([[1, 1, 1], [1, 1, 1]]), np.array([0, 0]))
    ]  # 2 m and 20.6 m from the path
    pred = BoxSet(
        np.array([[5.5, 2, 0]]), np.array([[1, 1, 1]]), np.array([0])
    )  # overlaps the near one by half: IoU 1/3
    matched = accuracy_matches(pred, np.array([[0.9]]), gt)
    np.testing.assert_allclose(matched[0], [1 / 3, np.nan])
    bands = iou_by_distance(matched, gt, path, bands=(5.0, 10.0))
    assert [(b["objects"], b["matched"]) for b in bands] == [(1, 1), (0, 0), (1, 0)]
    assert (
        bands[0]["matched_iou"] == pytest.approx(1 / 3) and bands[2]["matched_iou"] is None and bands[2]["to_m"] is None
    )


def test_matched_iou_is_the_mean_over_matches_only():
    gt = [BoxSet(np.array([[0, 0, 0], [10, 0, 0]]), np.array([[1, 1, 1], [1, 1, 1]]), np.array([0, 0]))]
    pred = BoxSet(
        np.array([[0, 0, 0], [40, 0, 0]]), np.array([[1, 1, 1], [1, 1, 1]]), np.array([0, 0])
    )  # one exact, one far off
    scores = evaluate_retrieval(pred, np.array([[0.9], [0.8]]), np.array([0, 0]), gt)
    assert scores.iou == pytest.approx(0.5) and scores.matched_iou == pytest.approx(1.0) and scores.matches == 1


def test_table_iii_runtime_is_building_the_regions_plus_one_query():
    from terra.eval.metrics.regions import SetScores
    from terra.eval.regions import MonitoringRun

    hierarchy = MonitoringRun([], [SetScores(1, 0, 0)] * 4, seconds=0.4, build_seconds=0.06)
    assert hierarchy.timing_ms() == pytest.approx({"regions_ms": 60.0, "query_ms": 100.0, "runtime_ms": 160.0})
    aib = MonitoringRun([], [SetScores(1, 0, 0)] * 4, seconds=4.0, cluster_seconds=3.6)  # clusters per query
    assert aib.timing_ms() == pytest.approx({"regions_ms": 900.0, "query_ms": 100.0, "runtime_ms": 1000.0})
