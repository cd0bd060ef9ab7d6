"""`terra serve` as a robot uses it: a real server process on a free loopback port (started here,
stopped after), answering with the CLI's JSON, refusing requests without the token, answering 100
concurrent requests as it answers them one by one, rejecting malformed bodies with one-line JSON
errors while it keeps serving, and saving objects one writer at a time."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from terra.bundle import Bundle, BundleWriter
from terra.cli import run
from tests.tasks.test_tasks_synthetic import dumpster_lot

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

TOKEN = "test-token-0123"
ROOT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Client:
    def __init__(self, url: str, token: str | None = TOKEN):
        self.url, self.token = url, token

    def call(
        self,
        method: str,
        path: str,
        body: bytes | dict | None = None,
        token: str | None = "default",
        headers: dict | None = None,
    ) -> tuple[int, dict, dict]:
        data = json.dumps(body).encode() if isinstance(body, dict) else body
        request = urllib.request.Request(self.url + path, data=data, method=method, headers=dict(headers or {}))
        token = self.token if token == "default" else token
        if token is not None:
            request.add_header("Authorization", f"Bearer {token}")
        if data is not None and "Content-Type" not in (headers or {}):
            request.add_header("Content-Type", "application/json")
        try:
            with urllib.request.urlopen(request, timeout=60) as response:
                raw = response.read()
                return response.status, json.loads(raw), dict(response.headers)
        except urllib.error.HTTPError as exc:
            raw = exc.read()
            assert raw.count(b"\n") == 0 and b"Traceback" not in raw  # one line, never a stack trace
            return exc.code, json.loads(raw), dict(exc.headers)


def write_lot(path: Path, text_embedder) -> Path:
    """The dumpster lot (map and scene graph) as a bundle at `path`."""
    from terra.graph.storage import write_scene_graph
    from terra.mapping.storage import write_map

    msm, graph, _ = dumpster_lot(text_embedder)
    with BundleWriter(path) as w:
        write_map(w, msm)
        write_scene_graph(w, graph)
    return path


@pytest.fixture(scope="module")
def served(text_embedder, tmp_path_factory):
    """(client, bundle path, server process) for a copy of the dumpster lot."""
    path = write_lot(tmp_path_factory.mktemp("serve") / "lot.terra", text_embedder)
    port = free_port()
    with open(path.parent / "serve.log", "w") as log:
        process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "terra",
                "serve",
                str(path),
                "--port",
                str(port),
                "--token",
                TOKEN,
                "--allow-writes",
            ],
            cwd=ROOT,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        client = Client(f"http://127.0.0.1:{port}")
        deadline = time.monotonic() + 180
        while True:
            try:
                if client.call("GET", "/health")[0] == 200:
                    break
            except (urllib.error.URLError, ConnectionError):
                pass
            assert process.poll() is None, (path.parent / "serve.log").read_text()
            assert time.monotonic() < deadline, "the server did not come up"
            time.sleep(0.3)
        yield client, path, process
        process.terminate()
        try:
            process.wait(20)
        except subprocess.TimeoutExpired:
            process.kill()


def cli_json(args: list[str], capsys) -> dict:
    assert run(args + ["--json"]) == 0, capsys.readouterr().err
    return json.loads(capsys.readouterr().out)


def test_the_service_answers_with_the_cli_json(served, capsys):
    client, path, _ = served
    b = str(path)
    pairs = [
        (
            ["find", b, "find the dumpster", "a car", "--alpha", "0.4"],
            "POST",
            "/find",
            {"queries": ["find the dumpster", "a car"], "alpha": 0.4},
        ),
        (
            ["find", b, "dumpster", "--method", "3dsg", "--alpha", "0.4"],
            "POST",
            "/find",
            {"queries": ["dumpster"], "method": "3dsg", "alpha": 0.4},
        ),
        (
            ["monitor", b, "dumpster", "--k", "1", "--alpha", "0.5"],
            "POST",
            "/monitor",
            {"queries": ["dumpster"], "k": 1, "alpha": 0.5},
        ),
        (["monitor", b, "dumpster", "--method", "aib"], "POST", "/monitor", {"queries": ["dumpster"], "method": "aib"}),
        (
            [
                "plan",
                b,
                "--to",
                "find the dumpster",
                "--alpha",
                "0.4",
                "--method",
                "ms-avg",
                "--from-xy",
                "5",
                "35",
                "--prefer",
                "sidewalk",
                "--penalty",
                "grass=2",
            ],
            "POST",
            "/plan",
            {
                "to": "find the dumpster",
                "alpha": 0.4,
                "method": "ms-avg",
                "from_xy": [5, 35],
                "prefer": ["sidewalk"],
                "penalty": {"grass": 2},
            },
        ),
        (
            ["plan", b, "--to-node", "0", "--from-node", "63", "--forbid", "asphalt"],
            "POST",
            "/plan",
            {"to_node": 0, "from_node": 63, "forbid": ["asphalt"]},
        ),
        (["node", b, "p9"], "GET", "/nodes/p9", None),
        (["node", b, "R0"], "GET", "/regions/1/0", None),
        (["node", b, "--at", "12.4", "7.6"], "GET", "/locate?x=12.4&y=7.6", None),
    ]
    for args, method, route, body in pairs:
        status, answer, _ = client.call(method, route, body)
        assert status == 200 and answer == cli_json(args, capsys), route
    # The start query of a plan, by its JSON name "from".
    status, answer, _ = client.call("POST", "/plan", {"to_node": 0, "from": "a car", "alpha": 0.4, "method": "ms-avg"})
    assert status == 200 and answer == cli_json(
        ["plan", b, "--to-node", "0", "--from", "a car", "--alpha", "0.4", "--method", "ms-avg"], capsys
    )


def test_the_token_is_required(served):
    client, _, _ = served
    for token in (None, "wrong-token-9876", TOKEN[:-1]):
        status, body, headers = client.call("GET", "/health", token=token)
        assert status == 401 and body["kind"] == "unauthorized" and headers.get("www-authenticate") == "Bearer"
        assert client.call("POST", "/find", {"queries": ["dumpster"]}, token=token)[0] == 401
        assert client.call("GET", "/no/such/endpoint", token=token)[0] == 401
    assert client.call("GET", "/openapi.json")[0] == 200


@pytest.mark.parametrize(
    "method, route, body, status, kind, message",
    [
        ("POST", "/find", b'{"queries": ["find the dumpster"', 400, "bad_request", "malformed JSON body"),
        ("POST", "/find", b"", 422, "invalid", "body"),
        ("POST", "/find", b"[1, 2]", 422, "invalid", "body"),
        ("POST", "/find", {"queries": "dumpster"}, 422, "invalid", "body.queries"),
        ("POST", "/find", {"queries": ["dumpster"], "colour": "red"}, 422, "invalid", "body.colour"),
        ("POST", "/find", {"queries": ["dumpster"], "method": "ms_trim"}, 422, "invalid", "body.method"),
        ("POST", "/find", {"queries": ["dumpster"], "alpha": 3}, 422, "invalid", "body.alpha"),
        ("POST", "/find", {"queries": ["  "]}, 400, "bad_request", "query 1 is empty"),
        ("POST", "/find", {"queries": []}, 400, "bad_request", "no query given"),
        ("POST", "/find", {"queries": ["dumpster"] * 33}, 413, "too_large", "at most 32 queries"),
        ("POST", "/find", {"queries": ["x" * 1001]}, 413, "too_large", "1001 characters"),
        ("POST", "/find", b'{"queries": ["' + b"a" * 70000 + b'"]}', 413, "too_large", "at most 65536"),
        ("POST", "/monitor", {"queries": ["dumpster"], "k": 0}, 422, "invalid", "body.k"),
        ("POST", "/plan", {"to": "dumpster", "forbid": ["gras"]}, 400, "bad_request", "unknown terrain 'gras'"),
        ("POST", "/plan", {"from_node": 0}, 400, "bad_request", "give a destination"),
        ("POST", "/plan", {"to_node": 0, "from_node": 63, "forbid": ["sidewalk"]}, 422, "no_path", "no path"),
        ("POST", "/plan", {"to_node": 500, "from_node": 0}, 400, "bad_request", "goal place 500 does not exist"),
        # The dumpster lot is hand-made, without ground geometry to check a robot against.
        ("POST", "/plan", {"to_node": 0, "from_node": 63, "robot": "wheelchair"}, 400, "bad_request", "no ground"),
        ("POST", "/plan", {"to_node": 0, "from_node": 63, "robot": "tank"}, 400, "bad_request", "unknown robot"),
        (
            "POST",
            "/plan",
            {"to_node": 0, "robot": {"max_step": -1, "max_slope_up": 8, "max_slope_down": 8}},
            422,
            "invalid",
            "body.robot",
        ),
        ("GET", "/nodes/p64", None, 404, "not_found", "place 64 does not exist"),
        ("GET", "/nodes/banana", None, 400, "bad_request", "expected a short name"),
        ("GET", "/regions/3/0", None, 404, "not_found", "region level 3"),
        ("GET", "/locate?x=abc&y=1", None, 422, "invalid", "query.x"),
        ("GET", "/no/such/endpoint", None, 404, "not_found", "no endpoint GET /no/such/endpoint"),
        ("GET", "/find", None, 405, "method_not_allowed", "GET is not allowed"),
    ],
)
def test_bad_requests_get_one_line_json_errors(served, method, route, body, status, kind, message):
    client, _, process = served
    got_status, answer, _ = client.call(method, route, body)
    assert (got_status, answer["kind"]) == (status, kind) and message in answer["error"], answer
    assert set(answer) == {"error", "kind"}
    assert client.call("GET", "/health")[0] == 200 and process.poll() is None  # still serving


def test_100_concurrent_requests_equal_the_sequential_answers(served):
    client, _, _ = served
    requests = [
        ("POST", "/find", {"queries": ["find the dumpster", "a car"], "alpha": 0.4}),
        ("POST", "/find", {"queries": ["dumpster"], "method": "3dsg", "alpha": 0.4}),
        ("POST", "/find", {"queries": ["a bench"], "method": "ms-max"}),
        ("POST", "/monitor", {"queries": ["dumpster", "car"], "k": 1, "alpha": 0.5}),
        (
            "POST",
            "/plan",
            {"to": "find the dumpster", "alpha": 0.4, "method": "ms-avg", "from_xy": [5, 35], "prefer": ["sidewalk"]},
        ),
        ("POST", "/plan", {"to_node": 0, "from_node": 63, "forbid": ["asphalt"]}),
        ("GET", "/nodes/p9", None),
        ("GET", "/locate?x=12.4&y=7.6", None),
        ("POST", "/plan", {"to_node": 0, "from_node": 63, "forbid": ["sidewalk"]}),  # an error answer too
    ]
    sequential = [client.call(*r)[:2] for r in requests]
    batch = [requests[i % len(requests)] for i in range(100)]
    with ThreadPoolExecutor(max_workers=32) as pool:
        answers = list(pool.map(lambda r: client.call(*r)[:2], batch))
    assert answers == [sequential[i % len(requests)] for i in range(100)]


def test_concurrent_saves_are_serialised_and_atomic(served, tmp_path):
    client, path, _ = served
    labels = ["find the dumpster", "a car", "dumpster", "car", "the green dumpster", "a parked car"]
    with ThreadPoolExecutor(max_workers=len(labels)) as pool:
        results = list(
            pool.map(lambda q: client.call("POST", "/find", {"queries": [q], "alpha": 0.4, "save": True}), labels)
        )
    assert all(status == 200 and body["saved"] for status, body, _ in results)
    from terra.graph.storage import load_scene_graph

    bundle = Bundle(path)
    bundle.verify()  # every file matches the manifest: no write interleaved with another
    saved = load_scene_graph(bundle)
    expected = sum(len(body["objects"]) for _, body, _ in results)
    assert len(saved.objects) == expected and set(saved.objects.label) == {
        q for q, (_, b, _) in zip(labels, results) if b["objects"]
    }
    status, first, _ = client.call("GET", "/nodes/O0")
    assert status == 200 and first["label"] in labels
    # The served graph is the saved one, and queries go on working on it.
    assert (
        client.call("GET", f"/nodes/O{expected - 1}")[0] == 200 and client.call("GET", f"/nodes/O{expected}")[0] == 404
    )
    assert client.call("POST", "/monitor", {"queries": ["dumpster"]})[0] == 200
    shutil.rmtree(tmp_path, ignore_errors=True)


def test_a_service_is_read_only_unless_started_with_allow_writes(text_embedder, tmp_path):
    from fastapi.testclient import TestClient

    from terra.loaded import LoadedBundle
    from terra.serve.app import create_app
    from terra.serve.config import ServeConfig
    from tests.mapping.fixtures import folder_digest

    path = write_lot(tmp_path / "lot.terra", text_embedder)
    before = folder_digest(path)
    client = TestClient(create_app(LoadedBundle(path), settings=ServeConfig()))
    answer = client.post("/find", json={"queries": ["find the dumpster"], "alpha": 0.4, "save": True})
    assert answer.status_code == 403 and answer.json()["kind"] == "read_only"
    assert "--allow-writes" in answer.json()["error"]
    assert folder_digest(path) == before
    # reading is still answered, and a writing service saves
    assert client.post("/find", json={"queries": ["find the dumpster"], "alpha": 0.4}).status_code == 200
    writer = TestClient(create_app(LoadedBundle(path), settings=ServeConfig(allow_writes=True)))
    saved = writer.post("/find", json={"queries": ["find the dumpster"], "alpha": 0.4, "save": True})
    assert saved.status_code == 200 and saved.json()["saved"] and folder_digest(path) != before


@pytest.mark.parametrize(
    "url", ["/nodes/" + "9" * 30, "/nodes/%C2%B2", "/nodes/" + "9" * 3000, "/locate?x=1e308&y=-1e308"]
)
def test_malformed_lookups_are_400_with_one_line(served, url):
    client, _, _ = served
    status, body, _ = client.call("GET", url)
    assert status == 400 and body["kind"] == "bad_request" and len(body["error"]) < 400, body


@pytest.mark.parametrize("endpoint", ["/find", "/monitor"])
def test_a_lone_surrogate_in_a_query_is_400(served, endpoint):
    client, _, _ = served
    status, body, _ = client.call("POST", endpoint, b'{"queries": ["park \\ud800 bench"]}')
    assert status == 400 and "lone UTF-16 surrogate" in body["error"], body
