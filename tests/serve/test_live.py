"""`terra serve --live`: frames pushed over HTTP (terra.live.wire) give the batch map byte for byte;
malformed frames are refused with the reason, counted and never fused; an oversized body is 413;
answers during live mapping name a version whose map and graph belong together; GET /live says how
long the source has been silent.

The batch references are tiny_bundle (the simulated tiny campus mapped in memory) and the same
drive written as a terra-folder and its frames mapped with `run_mapping`; examples/push_frames.py (numpy and
the standard library only) pushes the folder to a real `terra serve --live` process.
"""

from __future__ import annotations

import importlib.util
import io
import json
import shutil
import socket
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from terra.bundle import Bundle
from tests.live.test_session import FrameRange, map_files
from tests.mapping.fixtures import assert_same_map, folder_digest
from tests.serve.test_serve import ROOT, TOKEN, Client, free_port

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

EXAMPLE = ROOT / "examples" / "push_frames.py"


def load_example():
    spec = importlib.util.spec_from_file_location("push_frames", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


push_frames = load_example()


def frame_arrays(frame) -> dict[str, np.ndarray]:
    """A dataset Frame as the wire format's arrays (raw pixels and label images)."""
    arrays = {
        "points": frame.points,
        "T_map_lidar": frame.T_map_lidar,
        "stamp": np.float64(frame.stamp),
        "intensity": frame.intensity,
        "labels": frame.point_labels,
        "instances": frame.point_instances,
    }
    for c, camera in enumerate(frame.cameras):
        arrays |= {f"image_{c}": camera.image, f"image_stamp_{c}": np.float64(camera.stamp)}
        arrays |= {f"semantic_{c}": camera.semantic, f"instance_{c}": camera.instance}
    return {name: np.asarray(value) for name, value in arrays.items() if value is not None}


def cameras_of(frame) -> dict:
    from terra.datasets.folder_io import calibration_to_json

    return {"cameras": {str(c): calibration_to_json(cam.calibration) for c, cam in enumerate(frame.cameras)}}


def live_app(out: Path, dataset, graph: bool = False, service_class=None, token=None, **live):
    """(app, service) of a live service on a new bundle `out` with the dataset's classes."""
    from terra.live import Session
    from terra.serve.app import create_live_app
    from terra.serve.config import LiveConfig, ServeConfig
    from terra.serve.live import LiveService

    session = Session(out, dataset.classes, graph=graph, name=dataset.name)
    settings = LiveConfig(**{"update_every": 3600.0, **live})
    service = (service_class or LiveService)(session, settings)
    return create_live_app(service, settings=ServeConfig(allow_writes=True, token=token)), service


def post_frame(client, arrays: dict, **headers):
    body = push_frames.encode(arrays)
    return client.post("/frames", content=body, headers={"content-type": "application/x-npz", **headers})


def test_frames_pushed_over_http_give_the_batch_map(tiny_campus, tiny_bundle, tmp_path):
    from fastapi.testclient import TestClient

    out = tmp_path / "live.terra"
    app, _ = live_app(out, tiny_campus)
    with TestClient(app) as client:
        assert client.post("/cameras", json=cameras_of(tiny_campus[0])).json() == {"cameras": [0]}
        for i in range(len(tiny_campus)):
            answer = post_frame(client, frame_arrays(tiny_campus[i]))
            assert answer.status_code == 200 and answer.json() == {"fused": True, "frames": i + 1}
        committed = client.post("/snapshot").json()
        status = client.get("/live").json()
    assert committed["version"] == 1 and committed["frames"] == len(tiny_campus)
    assert committed["map_time"] == pytest.approx(tiny_campus[len(tiny_campus) - 1].stamp)
    assert (status["frames_received"], status["frames_fused"], status["frames_refused"]) == (40, 40, {})
    assert map_files(out) == map_files(tiny_bundle.path)


def zip_of(members: dict[str, bytes], compression=zipfile.ZIP_STORED) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return buffer.getvalue()


def npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, array, allow_pickle=True)
    return buffer.getvalue()


def malformed_bodies(frame) -> list[tuple[str, bytes, int, str, str]]:
    """(what, body, HTTP status, reason, words of the message) for frames the service must refuse."""
    good = frame_arrays(frame)
    encode = push_frames.encode
    compressed = io.BytesIO()
    np.savez_compressed(compressed, allow_pickle=False, **good)
    cases = [
        ("points (N, 2)", {"points": frame.points[:, :2]}, "bad_points", r"(N, 3)"),
        ("points as text", {"points": frame.points.astype(str)}, "bad_points", "expected numbers"),
        ("a NaN pose", {"T_map_lidar": np.full((4, 4), np.nan)}, "bad_pose", "NaN or infinity"),
        ("a scaled pose", {"T_map_lidar": np.diag([2.0, 1.0, 1.0, 1.0])}, "bad_pose", "not rigid"),
        ("a stamp going back", {"stamp": np.float64(frame.stamp - 100.0)}, "stamp_back", "does not follow"),
        ("labels of 3 points", {"labels": np.zeros(3, np.int32)}, "bad_labels", "one value per point"),
        ("an image of the wrong size", {"image_0": np.zeros((10, 10, 3), np.uint8)}, "bad_image", "(480, 640, 3)"),
        ("an image file that is none", {"image_0": np.arange(50, dtype=np.uint8)}, "bad_image", "not a JPEG or PNG"),
        ("a camera never calibrated", {"image_7": frame.cameras[0].image}, "bad_camera", "no calibration"),
        ("two poses", {"pose_xyz_quat": np.array([0, 0, 0, 0, 0, 0, 1.0])}, "bad_pose", "give either"),
        ("a pose with a stray array", {"colour": np.zeros(3)}, "bad_frame", "not an array of the frame"),
    ]
    no_pose = {k: v for k, v in good.items() if k != "T_map_lidar"}
    cases.append(("a quaternion of norm 2", {"pose_xyz_quat": np.array([0, 0, 0, 0, 0, 0, 2.0])}, "bad_pose", "unit"))
    bodies = [
        (what, encode({**(no_pose if "quaternion" in what else good), **change}), 400, reason, words)
        for what, change, reason, words in cases
    ]
    no_stamp = {k: v for k, v in good.items() if k != "stamp"}
    return bodies + [
        ("no stamp", encode(no_stamp), 400, "bad_frame", "stamp: missing"),
        ("not a zip", b"hello, robot", 400, "bad_frame", "expected an .npz"),
        ("a zip that is not a npz", zip_of({"notes.txt": b"hello"}), 400, "bad_frame", "not an array of the frame"),
        ("a damaged zip", encode(good)[:5000], 400, "bad_frame", "not a readable .npz"),
        (
            "an object array",
            zip_of({"points.npy": npy_bytes(np.array([{}], dtype=object))}),
            400,
            "bad_frame",
            "object",
        ),
        ("a compressed npz", compressed.getvalue(), 400, "bad_frame", "uncompressed"),
    ]


def test_malformed_frames_are_refused_with_the_reason_and_change_nothing(tiny_campus, tmp_path):
    from fastapi.testclient import TestClient

    out = tmp_path / "live.terra"
    app, _ = live_app(out, tiny_campus)
    cases = malformed_bodies(tiny_campus[1])
    with TestClient(app) as client:
        client.post("/cameras", json=cameras_of(tiny_campus[0]))
        assert post_frame(client, frame_arrays(tiny_campus[0])).status_code == 200
        assert client.post("/snapshot").json()["version"] == 1
        before = folder_digest(out)
        shutil.copytree(out, tmp_path / "version1.terra")
        for what, body, status, reason, words in cases:
            answer = client.post("/frames", content=body, headers={"content-type": "application/x-npz"})
            assert (answer.status_code, answer.json()["kind"]) == (status, reason), (what, answer.json())
            assert words in answer.json()["error"] and "\n" not in answer.json()["error"], what
        assert client.post("/snapshot").json()["version"] == 1  # nothing new to commit
        live = client.get("/live").json()
        assert client.get("/health").json()["version"] == 1
        assert folder_digest(out) == before  # never fused, never a new version
    expected: dict[str, int] = {}
    for _, _, _, reason, _ in cases:
        expected[reason] = expected.get(reason, 0) + 1
    assert live["frames_refused"] == expected and live["frames_fused"] == 1
    assert live["frames_received"] == 1 + len(cases) and live["version"] == 1
    # Closing the service writes version 1's map once more as the final version (the flat layout
    # batch runs write, terra/mapping/chunks.py): the same map, nothing of the refused frames.
    assert Bundle(out).version == 2
    assert_same_map(out, tmp_path / "version1.terra")


def test_an_oversized_frame_is_413_before_its_body_is_read(tiny_campus, tmp_path):
    import uvicorn
    from fastapi.testclient import TestClient

    app, service = live_app(tmp_path / "live.terra", tiny_campus, max_frame_bytes=64 << 10)
    with TestClient(app) as client:
        body = push_frames.encode(frame_arrays(tiny_campus[0]))
        answer = client.post("/frames", content=body)
        assert answer.status_code == 413 and f"at most {64 << 10}" in answer.json()["error"]
        chunked = client.post("/frames", content=iter([body[i : i + 4096] for i in range(0, len(body), 4096)]))
        assert chunked.status_code == 413 and "over 65536 bytes" in chunked.json()["error"]
        assert client.post("/find", content=b"x" * 70000).status_code == 413  # JSON bodies keep their own limit
    assert service.counters.received == 0 and not (tmp_path / "live.terra").exists()
    # A real server answers a declared 1 GB body at once, without waiting for a byte of it.
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        wait_until_up(Client(f"http://127.0.0.1:{port}", token=None))
        with socket.create_connection(("127.0.0.1", port), timeout=20) as raw:
            raw.sendall(b"POST /frames HTTP/1.1\r\nHost: x\r\nContent-Length: 1000000000\r\n\r\n")
            reply = b""
            while b"too_large" not in reply and (chunk := raw.recv(4096)):
                reply += chunk
        assert reply.startswith(b"HTTP/1.1 413") and b"too_large" in reply
    finally:
        server.should_exit = True
        thread.join(30)


def test_writes_need_allow_writes_and_the_token(tiny_campus, tmp_path):
    from fastapi.testclient import TestClient

    from terra.live import Session
    from terra.serve.app import create_live_app
    from terra.serve.config import ServeConfig
    from terra.serve.live import LiveService

    body = push_frames.encode(frame_arrays(tiny_campus[0]))
    app, service = live_app(tmp_path / "token.terra", tiny_campus, token=TOKEN)
    with TestClient(app) as client:
        assert client.post("/frames", content=body).status_code == 401
        assert (
            client.post("/frames", content=body, headers={"authorization": "Bearer wrong-token-9"}).status_code == 401
        )
        authorised = {"authorization": f"Bearer {TOKEN}"}
        client.post("/cameras", json=cameras_of(tiny_campus[0]), headers=authorised)
        assert client.post("/frames", content=body, headers=authorised).json()["fused"] is True
    session = Session(tmp_path / "read-only.terra", tiny_campus.classes, graph=False)
    with TestClient(create_live_app(LiveService(session), settings=ServeConfig())) as client:
        answer = client.post("/frames", content=body)
        assert answer.status_code == 403 and "--allow-writes" in answer.json()["error"]
        assert client.post("/cameras", json=cameras_of(tiny_campus[0])).status_code == 403
    assert session.frames == 0 and not (tmp_path / "read-only.terra").exists()


def test_a_stalled_source_is_reported_and_the_service_keeps_answering(tiny_campus, tmp_path):
    from fastapi.testclient import TestClient

    app, _ = live_app(tmp_path / "live.terra", tiny_campus)
    with TestClient(app) as client:
        waiting = client.get("/live").json()
        assert waiting["seconds_since_last_frame"] is None and waiting["version"] is None
        early = client.post("/find", json={"queries": ["bench"]})
        assert early.status_code == 503 and early.json()["kind"] == "not_ready"
        client.post("/cameras", json=cameras_of(tiny_campus[0]))
        post_frame(client, frame_arrays(tiny_campus[0]))
        pushed = time.monotonic()
        time.sleep(1.5)
        status = client.get("/live").json()
        silent = time.monotonic() - pushed
        assert 1.5 <= status["seconds_since_last_frame"] <= silent + 0.01
        assert status["frames_fused"] == 1 and status["frames_pending"] == 1
        assert client.get("/health").status_code == 200


def test_a_live_service_continues_a_bundle_with_its_own_classes(tiny_campus, tiny_bundle, tmp_path):
    """`terra serve BUNDLE --live` on a bundle it wrote: its classes and kept state, queries answered
    on the resumed version at once, and the rest of the drive ending with the batch map."""
    from fastapi.testclient import TestClient

    from terra.cli.serve import open_live_service
    from terra.datasets.folder_io import write_classes
    from terra.errors import TerraError
    from terra.serve.app import create_live_app
    from terra.serve.config import LiveConfig, ServeConfig

    out, cut = tmp_path / "live.terra", len(tiny_campus) // 2
    app, _ = live_app(out, tiny_campus)
    with TestClient(app) as client:  # stopping commits what was fused
        client.post("/cameras", json=cameras_of(tiny_campus[0]))
        for i in range(cut):
            post_frame(client, frame_arrays(tiny_campus[i]))
    with pytest.raises(TerraError, match="needs its class table"):
        open_live_service(tmp_path / "new.terra", None, None)
    other = tmp_path / "other"
    other.mkdir()
    write_classes(other, type(tiny_campus.classes)(tiny_campus.classes.classes[:3]))
    with pytest.raises(TerraError, match="the classes differ"):
        open_live_service(out, other / "classes.json", None, tiny_campus.name)
    service = open_live_service(out, None, None, tiny_campus.name, LiveConfig(update_every=3600))
    assert service.session.classes.to_json() == tiny_campus.classes.to_json() and service.session.frames == cut
    with TestClient(create_live_app(service, settings=ServeConfig(allow_writes=True))) as client:
        first = client.get("/health").json()
        assert first["version"] == Bundle(out).version and first["map_time"] == tiny_campus[cut - 1].stamp
        client.post("/cameras", json=cameras_of(tiny_campus[0]))
        for i in range(cut, len(tiny_campus)):
            assert post_frame(client, frame_arrays(tiny_campus[i])).json()["fused"] is True
    assert map_files(out) == map_files(tiny_bundle.path)


def test_the_update_thread_commits_by_frames_and_by_time(tiny_campus, tmp_path):
    from fastapi.testclient import TestClient

    def wait_for_version(client, version: int) -> dict:
        deadline = time.monotonic() + 120
        while (status := client.get("/live").json())["version"] != version:
            assert time.monotonic() < deadline, status
            time.sleep(0.1)
        return status

    app, _ = live_app(tmp_path / "frames.terra", tiny_campus, update_frames=3)
    with TestClient(app) as client:
        client.post("/cameras", json=cameras_of(tiny_campus[0]))
        for i in range(3):
            post_frame(client, frame_arrays(tiny_campus[i]))
        status = wait_for_version(client, 1)  # three frames: committed without waiting an hour
        assert status["frames_pending"] == 0 and status["updates"] == 1 and status["last_update_error"] == ""
        assert client.get("/health").json()["map_time"] == tiny_campus[2].stamp
    app, _ = live_app(tmp_path / "time.terra", tiny_campus, update_every=0.5)
    with TestClient(app) as client:
        client.post("/cameras", json=cameras_of(tiny_campus[0]))
        post_frame(client, frame_arrays(tiny_campus[0]))
        assert wait_for_version(client, 1)["frames_fused"] == 1
        post_frame(client, frame_arrays(tiny_campus[1]))
        assert wait_for_version(client, 2)["map_time"] == tiny_campus[1].stamp


def test_live_options_without_live_are_refused(tmp_path, capsys):
    from terra.cli import run

    assert run(["serve", str(tmp_path / "lot.terra"), "--classes", str(tmp_path / "classes.json")]) == 2
    assert "--classes and --update-frames are for --live" in capsys.readouterr().err


class RecordingService:
    """A LiveService that keeps the manifest of every version it commits (the test's independent record)."""

    @staticmethod
    def make():
        from terra.serve.live import LiveService

        class Recording(LiveService):
            manifests: dict[int, dict] = {}

            def update(self):
                snapshot = super().update()
                if snapshot is not None:
                    manifest = json.loads((self.session.out / "manifest.json").read_text())
                    self.manifests[manifest["version"]] = manifest
                return snapshot

        return Recording


def test_answers_during_live_mapping_name_a_consistent_version(tiny_campus, tmp_path):
    """A pusher commits every 6 frames while a reader asks; each answer's counts are those of the
    manifest of the version it names (the graph built on that version's map)."""
    import uvicorn

    app, service = live_app(tmp_path / "live.terra", tiny_campus, graph=True, service_class=RecordingService.make())
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    client = Client(f"http://127.0.0.1:{port}", token=None)
    answers: list[tuple[str, dict]] = []
    done = threading.Event()

    def ask() -> None:
        while not done.is_set():
            for route, body in (("/health", None), ("/find", {"queries": ["bicycle rack", "bench"]})):
                status, answer, _ = client.call("GET" if body is None else "POST", route, body)
                if status == 200 and answer.get("status") != "waiting":  # waiting: before the first version
                    answers.append((route, answer))

    try:
        wait_until_up(client)
        client.call("POST", "/cameras", cameras_of(tiny_campus[0]))
        reader = threading.Thread(target=ask)
        reader.start()
        for i in range(24):
            body = push_frames.encode(frame_arrays(tiny_campus[i]))
            assert client.call("POST", "/frames", body, headers={"Content-Type": "application/x-npz"})[0] == 200
            if i % 6 == 5:
                assert client.call("POST", "/snapshot", {})[0] == 200
        time.sleep(1.0)
        done.set()
        reader.join(120)
    finally:
        done.set()
        server.should_exit = True
        thread.join(60)
    manifests = service.manifests
    versions = {answer["version"] for _, answer in answers}
    assert len(versions) >= 3, versions  # answered while the map grew
    for route, answer in answers:
        manifest = manifests[answer["version"]]
        graph, mapped = manifest["components"].get("graph"), manifest["components"]["map"]
        places = graph["places"] if graph is not None else 0
        if route == "/health":
            assert (answer["points"], answer["places"]) == (mapped["points"], places), answer["version"]
        else:
            assert all(obj["place"] < places for obj in answer["objects"]), answer["version"]
        assert graph is None or graph["map_version"] == mapped["version"]  # the graph of this map
        frames = mapped["frames"]
        assert answer["map_time"] == pytest.approx(tiny_campus[frames - 1].stamp)


def wait_until_up(client: Client, seconds: float = 120.0) -> None:
    deadline = time.monotonic() + seconds
    while True:
        try:
            if client.call("GET", "/live")[0] == 200:
                return
        except (OSError, ConnectionError):
            pass
        assert time.monotonic() < deadline, "the server did not come up"
        time.sleep(0.2)


# ----------------------------------------------------------------- the robot-side example, end to end
@pytest.fixture(scope="module")
def tiny_folder(tiny_campus, tmp_path_factory) -> Path:
    """The tiny drive written as a terra-folder (JPEG images, label PNGs, poses as xyz + quaternion)."""
    from terra.sim.writer import write_dataset

    return write_dataset(tiny_campus, tmp_path_factory.mktemp("live-folder") / "tiny", progress=False)


@pytest.mark.slow
def test_the_example_pushes_a_folder_to_a_live_service_and_gets_the_batch_map(tiny_folder, tmp_path):
    from terra.datasets.terra_folder import TerraFolderDataset
    from terra.mapping.config import MappingConfig
    from terra.mapping.pipeline import run_mapping

    dataset = TerraFolderDataset(tiny_folder)
    # The batch of the same frames: FrameRange has no global map (the folder's global_pc, which
    # `terra map FOLDER` fuses onto by default; a live map grows its own voxels).
    frames = FrameRange(dataset, 0, len(dataset))
    batch = run_mapping(frames, MappingConfig(), tmp_path / "batch.terra", show_progress=False).bundle.path
    out, port = tmp_path / "live.terra", free_port()
    command = [
        sys.executable,
        "-m",
        "terra",
        "serve",
        str(out),
        "--live",
        "--classes",
        str(tiny_folder / "classes.json"),
    ]
    command += ["--allow-writes", "--token", TOKEN, "--port", str(port), "--name", dataset.name, "--update-every", "1"]
    log = tmp_path / "serve.log"
    with open(log, "w") as sink:
        server = subprocess.Popen(command, cwd=ROOT, stdout=sink, stderr=subprocess.STDOUT)
    try:
        wait_until_up(Client(f"http://127.0.0.1:{port}"))
        # Terra is not importable in the pusher: the example needs numpy and the standard library only.
        script = (
            f"import sys; sys.modules['terra'] = None; sys.argv[0] = {str(EXAMPLE)!r}; exec(open(sys.argv[0]).read())"
        )
        pushed = subprocess.run(
            [
                sys.executable,
                "-c",
                script,
                str(tiny_folder),
                f"http://127.0.0.1:{port}",
                "--token",
                TOKEN,
                "--snapshot",
            ],
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert pushed.returncode == 0, pushed.stdout + pushed.stderr
        summary = json.loads(pushed.stdout.strip().splitlines()[-1])
        assert summary["sent"] == len(dataset) and summary["refused"] == 0 and summary["version"] >= 1
        status, live, _ = Client(f"http://127.0.0.1:{port}").call("GET", "/live")
        assert status == 200 and live["frames_fused"] == len(dataset) and live["frames_pending"] == 0
    finally:
        server.terminate()
        server.wait(60)
    assert server.returncode in (0, -15), log.read_text()
    assert map_files(out) == map_files(batch)
    Bundle(out).verify()
