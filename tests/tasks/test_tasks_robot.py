"""Robot profiles at planning time (terra.tasks.robot): a wheelchair that must use the curb cut and
avoid the stairs on hand-made ground, slope costs against hand-computed values, profile files,
task files, config and requests, and bad profiles (one line, exit code 2)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from terra.cli import run
from terra.errors import NoPathError, TerraError
from terra.graph.grid import GridFrame
from terra.graph.ground import edge_geometry, ground_layers
from terra.graph.scene_graph import EDGE_GVD, Places, SceneGraph
from terra.tasks.planning import plan_path
from terra.tasks.requests import PlanRequest
from terra.tasks.robot import ROBOTS, RobotProfile

WIDTH, DEPTH, CELL = 20.0, 10.0, 0.4


def lattice_graph(height, spacing: float = 1.0) -> SceneGraph:
    """Places every `spacing` metres over a WIDTH x DEPTH m patch of ground whose height is
    `height(x, y)` (metres), linked to their 8 neighbours, with the ground geometry of every edge
    from dense points of that ground (terra.graph.ground)."""
    rng = np.random.default_rng(0)
    xy = rng.uniform([0.0, 0.0], [WIDTH, DEPTH], (160_000, 2))
    points = np.column_stack([xy, height(xy[:, 0], xy[:, 1])])
    layers = ground_layers(points, GridFrame((0.0, 0.0), (int(DEPTH / CELL), int(WIDTH / CELL)), CELL))
    xs = np.arange(spacing / 2, WIDTH, spacing)
    ys = np.arange(spacing / 2, DEPTH, spacing)
    gx, gy = np.meshgrid(xs, ys)
    position = np.column_stack([gx.ravel(), gy.ravel(), height(gx.ravel(), gy.ravel())])
    index = np.arange(len(position)).reshape(gx.shape)
    neighbours = [
        (index[:, :-1], index[:, 1:]),
        (index[:-1, :], index[1:, :]),
        (index[:-1, :-1], index[1:, 1:]),
        (index[:-1, 1:], index[1:, :-1]),
    ]
    pairs = [np.column_stack([a.ravel(), b.ravel()]) for a, b in neighbours]
    edges = np.sort(np.vstack(pairs), axis=1)
    length = np.linalg.norm(position[edges[:, 0]] - position[edges[:, 1]], axis=1)
    P = len(position)
    return SceneGraph(
        terrain_classes=["ground"],
        terrain_embeddings=np.eye(1, 4, dtype=np.float32),
        places=Places(
            position, np.zeros(P, np.int64), np.full(P, 2.0), np.tile(np.eye(1, 4, dtype=np.float32), (P, 1))
        ),
        place_edges=edges,
        place_edge_weight=length,
        place_edge_kind=np.full(len(edges), EDGE_GVD),
        place_edge_geometry=edge_geometry(layers, position, edges),
    )


def nearest(graph: SceneGraph, x: float, y: float) -> int:
    return int(np.argmin(np.linalg.norm(graph.places.position[:, :2] - [x, y], axis=1)))


def curb_with_cut(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A road (y < 5, z = 0) and a sidewalk 15 cm up behind a curb at y = 5, except at a curb cut
    (8 <= x < 12) where the sidewalk ramps down to the road over y = 5..7 (4.3 degrees)."""
    cut = (x >= 8.0) & (x < 12.0)
    walk = np.where(cut, 0.15 * np.clip((y - 5.0) / 2.0, 0.0, 1.0), 0.15)
    return np.where(y >= 5.0, walk, 0.0)


@pytest.fixture(scope="module")
def curb_graph() -> SceneGraph:
    return lattice_graph(curb_with_cut)


def crossing_x(graph: SceneGraph, places: np.ndarray) -> float:
    """x where a path crosses the curb line y = 5 (the mean x of the step that crosses it)."""
    y = graph.places.position[places, 1]
    k = int(np.flatnonzero((y[:-1] < 5.0) & (y[1:] >= 5.0))[0])
    return float(graph.places.position[places[k : k + 2], 0].mean())


def test_a_wheelchair_crosses_the_curb_only_at_the_cut(curb_graph):
    start, goal = nearest(curb_graph, 2.5, 1.5), nearest(curb_graph, 2.5, 8.5)
    free = plan_path(curb_graph, start, goal)
    assert crossing_x(curb_graph, free.places) < 4.0  # straight over the curb
    assert free.ground is not None and free.ground.max_step_m == pytest.approx(0.15, abs=0.03)
    chair = plan_path(curb_graph, start, goal, robot=ROBOTS["wheelchair"])
    assert 8.0 <= crossing_x(curb_graph, chair.places) < 12.0
    assert chair.ground is not None and chair.ground.max_step_m <= 0.05
    assert chair.ground.max_slope_deg <= 8.0
    assert chair.length_m > free.length_m + 8.0  # the detour to the cut and back
    legged = plan_path(curb_graph, start, goal, robot=ROBOTS["legged"])  # 15 cm is within its 20
    assert crossing_x(curb_graph, legged.places) < 4.0


def stairs_and_ramp(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A lower plaza (y < 4, z = 0) and an upper one (y > 5.2, z = 0.6) joined by four 15 cm steps
    (y = 4..5.2, 26.6 degrees) for x < 12; for x >= 12 a ramp rising 0.6 m over the whole depth
    (3.4 degrees)."""
    stairs = 0.15 * np.clip(np.floor((y - 4.0) / 0.3) + 1.0, 0.0, 4.0)
    return np.where(x < 12.0, stairs, 0.6 * np.clip(y / DEPTH, 0.0, 1.0))


def test_stairs_are_avoided_by_wheels_and_taken_by_legs():
    graph = lattice_graph(stairs_and_ramp)
    start, goal = nearest(graph, 2.5, 1.5), nearest(graph, 2.5, 8.5)
    stairs = plan_path(graph, start, goal, robot=ROBOTS["legged"])
    assert graph.places.position[stairs.places, 0].max() < 12.0  # up the stairs
    for name in ("wheelchair", "wheeled"):
        plan = plan_path(graph, start, goal, robot=ROBOTS[name])
        assert graph.places.position[plan.places, 0].max() >= 12.0, name  # round by the ramp
        assert plan.ground is not None and plan.ground.max_slope_deg <= ROBOTS[name].max_slope_up
        assert plan.ground.max_step_m <= ROBOTS[name].max_step


def two_places(
    rise: float, fall: float = 0.0, step: float = 0.0, unobserved: float = 0.0, cross: float = 0.0
) -> SceneGraph:
    """Two places 10 m apart on one edge whose ground geometry is given by hand."""
    position = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    return SceneGraph(
        terrain_classes=["ground"],
        terrain_embeddings=np.eye(1, 4, dtype=np.float32),
        places=Places(
            position, np.zeros(2, np.int64), np.full(2, 2.0), np.tile(np.eye(1, 4, dtype=np.float32), (2, 1))
        ),
        place_edges=np.array([[0, 1]]),
        place_edge_weight=np.array([10.0]),
        place_edge_kind=np.array([EDGE_GVD]),
        place_edge_geometry=np.array([[step, rise, fall, unobserved, cross]], dtype=np.float32),
    )


def test_slope_cost_by_hand():
    robot = RobotProfile(name="test", max_step=0.1, max_slope_up=8.0, max_slope_down=16.0, slope_cost=2.0)
    graph = two_places(rise=4.0)
    # Up 4 of 8 degrees: 10 m x (1 + 2 x 4 / 8) = 20; back down 4 of 16: 10 x (1 + 2 x 4 / 16) = 15.
    assert plan_path(graph, 0, 1, robot=robot).cost == pytest.approx(20.0)
    assert plan_path(graph, 1, 0, robot=robot).cost == pytest.approx(15.0)
    assert plan_path(graph, 0, 1).cost == pytest.approx(10.0)  # no robot: no slope cost
    # With terrain penalties on top: 10 x (1 + 1.5) x (1 + 2 x 4 / 8) = 50.
    assert plan_path(graph, 0, 1, penalties={"ground": 1.5}, robot=robot).cost == pytest.approx(50.0)
    steep = two_places(rise=9.0)  # over 8 up, within 16 down
    with pytest.raises(NoPathError, match="robot 'test'"):
        plan_path(steep, 0, 1, robot=robot)
    assert plan_path(steep, 1, 0, robot=robot).cost == pytest.approx(10.0 * (1 + 2 * 9.0 / 16.0))
    with pytest.raises(NoPathError):
        plan_path(two_places(rise=0.0, step=0.12), 0, 1, robot=robot)  # a 12 cm step over its 10
    narrow = RobotProfile(name="wide", max_step=0.1, max_slope_up=8, max_slope_down=8, min_width=4.5)
    with pytest.raises(NoPathError):
        plan_path(graph, 0, 1, robot=narrow)  # clearance 2 m: a 4 m passage for a 4.5 m robot


def test_an_edge_over_a_long_unobserved_stretch_is_refused():
    """The edge's 10 m, 6 of them over ground the map never observed: beyond the built-in profiles'
    5 m, within a profile's 8; a graph that does not record the stretch (NaN) is planned as before."""
    chair = ROBOTS["wheelchair"]
    assert chair.max_unobserved == 5.0
    with pytest.raises(NoPathError, match="unobserved ground up to 5 m"):
        plan_path(two_places(rise=0.0, unobserved=6.0), 0, 1, robot=chair)
    plan = plan_path(two_places(rise=0.0, unobserved=4.0), 0, 1, robot=chair)
    assert plan.ground is not None and plan.ground.max_unobserved_m == pytest.approx(4.0)
    assert plan.cost == pytest.approx(10.0)
    trusting = chair.model_copy(update={"max_unobserved": 8.0})
    assert plan_path(two_places(rise=0.0, unobserved=6.0), 0, 1, robot=trusting).cost == pytest.approx(10.0)
    unrecorded = plan_path(two_places(rise=0.0, unobserved=np.nan), 0, 1, robot=chair)
    assert unrecorded.ground is not None and unrecorded.ground.max_unobserved_m is None
    assert unrecorded.ground.to_json()["max_unobserved_m"] is None
    assert plan_path(two_places(rise=0.0, unobserved=6.0), 0, 1).cost == pytest.approx(10.0)  # no robot, no rule


def test_an_edge_along_a_side_slope_steeper_than_the_limit_is_refused():
    """An edge climbing 2 degrees along a hillside 11 degrees steep across it: refused both ways by
    the wheelchair (side slopes up to its climbs' 8 degrees) and by a profile limiting side slopes
    to 10; kept by one allowing 12; a graph that does not record it (NaN) is planned as before."""
    chair = ROBOTS["wheelchair"]
    assert chair.cross_limit == 8.0
    hillside = two_places(rise=2.0, cross=11.0)
    for a, b in ((0, 1), (1, 0)):
        with pytest.raises(NoPathError, match="side slopes up to 8 deg"):
            plan_path(hillside, a, b, robot=chair)
    assert RobotProfile(name="s", max_step=0.1, max_slope_up=12, max_slope_down=4).cross_limit == 12.0
    tippy = RobotProfile(name="tippy", max_step=0.1, max_slope_up=12, max_slope_down=12, max_cross_slope=10)
    with pytest.raises(NoPathError):
        plan_path(hillside, 0, 1, robot=tippy)
    steady = tippy.model_copy(update={"max_cross_slope": 12.0})
    plan = plan_path(hillside, 0, 1, robot=steady)
    # The side slope adds no cost: 10 m x (1 + 1 x 2 / 12).
    assert plan.cost == pytest.approx(10.0 * (1 + 2.0 / 12.0))
    assert plan.ground is not None and plan.ground.max_cross_slope_deg == pytest.approx(11.0)
    unrecorded = plan_path(two_places(rise=2.0, cross=np.nan), 0, 1, robot=chair)
    assert unrecorded.ground is not None and unrecorded.ground.to_json()["max_cross_slope_deg"] is None


def test_a_graph_without_ground_geometry_refuses_a_robot():
    graph = two_places(rise=0.0)
    graph.place_edge_geometry = np.zeros((0, 5), dtype=np.float32)
    with pytest.raises(TerraError, match="no ground geometry"):
        plan_path(graph, 0, 1, robot=ROBOTS["wheelchair"])
    assert plan_path(graph, 0, 1).ground is None


def plan_json(capsys, argv: list[str]) -> dict:
    capsys.readouterr()
    assert run(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_robot_from_flag_file_task_file_and_config(lidar_only_bundle, tmp_path, capsys):
    base = ["plan", str(lidar_only_bundle), "--from-node", "0", "--to-node", "3", "--json"]
    assert plan_json(capsys, base)["robot"] is None
    out = plan_json(capsys, [*base, "--robot", "wheelchair"])
    assert out["robot"]["name"] == "wheelchair" and out["ground"]["max_step_m"] <= 0.05
    assert out["ground"]["max_slope_deg"] <= 8.0
    assert out["robot"]["max_cross_slope"] == 8.0 and out["ground"]["max_cross_slope_deg"] <= 8.0
    profile = tmp_path / "scooter.yaml"
    profile.write_text("max_step: 0.08\nmax_slope_up: 10\nmax_slope_down: 12\nterrain_costs: {ground: 0.5}\n")
    out = plan_json(capsys, [*base, "--robot", str(profile)])
    assert out["robot"]["name"] == "scooter" and out["preferences"]["penalty"] == {"ground": 0.5}
    tasks = tmp_path / "tasks.yaml"
    tasks.write_text("robot: legged\n")
    assert plan_json(capsys, [*base, "--tasks", str(tasks)])["robot"]["name"] == "legged"
    config = tmp_path / "terra.yaml"
    config.write_text(
        "tasks:\n  planning:\n    robot: {name: cart, max_step: 0.1, max_slope_up: 6, max_slope_down: 6}\n"
    )
    assert plan_json(capsys, [*base, "--config", str(config)])["robot"]["name"] == "cart"
    # The flag wins over the task file.
    assert plan_json(capsys, [*base, "--tasks", str(tasks), "--robot", "wheeled"])["robot"]["name"] == "wheeled"


def test_a_request_carries_a_profile_as_json():
    request = PlanRequest.model_validate(
        {"to_node": 3, "from_node": 0, "robot": {"max_step": 0.05, "max_slope_up": 8, "max_slope_down": 8}}
    )
    assert isinstance(request.robot, RobotProfile) and request.robot.max_step == 0.05
    assert PlanRequest.model_validate({"to_node": 3, "robot": "wheelchair"}).robot == "wheelchair"


@pytest.mark.parametrize(
    ("text", "expect"),
    [
        ("max_step: 0.05\nmax_slope_up: 8\nmax_slope_down: 8\nwheels: 4\n", "field 'wheels': Extra inputs"),
        ("max_step: -0.05\nmax_slope_up: 8\nmax_slope_down: 8\n", "field 'max_step': Input should be greater"),
        ("max_step: 0.05\nmax_slope_up: 95\nmax_slope_down: 8\n", "field 'max_slope_up': Input should be less"),
        ("max_step: 0.05\nmax_slope_up: 8\n", "field 'max_slope_down': Field required"),
        (
            "max_step: 0.05\nmax_slope_up: 8\nmax_slope_down: 8\nmax_cross_slope: -1\n",
            "field 'max_cross_slope': Input should be greater",
        ),
        ("- 0.05\n", "expected a mapping"),
    ],
)
def test_bad_profile_files(lidar_only_bundle, tmp_path, capsys, text, expect):
    profile = tmp_path / "robot.yaml"
    profile.write_text(text)
    capsys.readouterr()
    assert run(["plan", str(lidar_only_bundle), "--from-node", "0", "--to-node", "3", "--robot", str(profile)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and expect in err and str(profile) in err
    assert captured.out == ""


def test_an_unknown_robot_name(lidar_only_bundle, tmp_path, capsys):
    capsys.readouterr()
    assert run(["plan", str(lidar_only_bundle), "--to-node", "3", "--from-node", "0", "--robot", "tank"]) == 2
    assert "--robot 'tank': expected wheelchair, wheeled, legged" in capsys.readouterr().err
    tasks = tmp_path / "tasks.yaml"
    tasks.write_text("robot: tank\n")
    assert run(["plan", str(lidar_only_bundle), "--to-node", "3", "--from-node", "0", "--tasks", str(tasks)]) == 2
    assert "unknown robot 'tank'" in capsys.readouterr().err
