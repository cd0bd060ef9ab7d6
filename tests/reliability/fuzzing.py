"""Mutation fuzzing of Terra's readers through its command line, shared by the test suite
(tests/reliability/test_fuzz_readers.py: hypothesis drives the mutations, a fixed budget) and the benchmark
(benchmarks/fuzz_readers.py: >= 10,000 inputs in worker processes that may crash or hang).

A target names a seed (a tiny dataset of each format, a bundle with map and scene graph, the
authors' reference files, config, task and msmap files), the files of it to mutate, how (structured
JSON / YAML edits, .npy dtype / shape / value edits, byte edits, or swapping a file for a folder,
a FIFO, a link out of the folder, or nothing) and the command that reads them. Every run of a
mutated input is judged against Terra's promise: exit 0 with a valid result (a written bundle
opens, verifies and loads) or exit 2 with exactly one line; never another exit code, an exception
(a traceback), a hang; an input bundle that is not the command's output left byte for byte
unchanged, and nothing written outside the output path.

Run as `python -m tests.reliability.fuzzing worker` it reads jobs `{"target", "seed", "seeds"}` (one JSON line
each) and answers one JSON line per job: the benchmark's supervisor observes crashes and hangs.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import random
import shutil
import signal
import sys
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from tests.reliability.families import Family, Made, copy_family_seed, families, judge_response, run_request

if TYPE_CHECKING:
    import subprocess

QUERY = "find the dumpster"
INTERESTING_INTS = [0, 1, -1, 2, 255, 256, 65535, 65536, 2**31 - 1, -(2**31), 2**32, 2**63 - 1, -(2**63), 2**64, 10**12]
INTERESTING_FLOATS = [0.0, -0.0, 1.5, -1.0, 1e-300, 1e300, -1e300, 1e308, float("nan"), float("inf"), float("-inf")]


# ------------------------------------------------------------------------------------------ seeds
@dataclass
class Seeds:
    """Paths of the seed inputs (all under `root`)."""

    root: Path
    datasets: dict[str, Path] = field(default_factory=dict)  # format -> dataset folder (or bag file)
    bundle: Path | None = None
    reference: Path | None = None
    config: Path | None = None
    tasks: Path | None = None
    msmap: Path | None = None

    def to_json(self) -> dict:
        return {
            "root": str(self.root),
            "datasets": {k: str(v) for k, v in self.datasets.items()},
            "bundle": str(self.bundle),
            "reference": str(self.reference),
            "config": str(self.config),
            "tasks": str(self.tasks),
            "msmap": str(self.msmap),
        }

    @classmethod
    def from_json(cls, d: dict) -> Seeds:
        return cls(
            Path(d["root"]),
            {k: Path(v) for k, v in d["datasets"].items()},
            Path(d["bundle"]),
            Path(d["reference"]),
            Path(d["config"]),
            Path(d["tasks"]),
            Path(d["msmap"]),
        )


def cli(argv: Sequence[str | Path]) -> tuple[int, str, str]:
    """Run `terra argv` in this process: (exit code, stdout, stderr). Exceptions propagate."""
    from terra.cli import run

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = run([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def build_seeds(root: Path, frames: int = 3) -> Seeds:
    """A tiny simulated campus (`frames` frames) in every dataset format, its bundle with a scene
    graph, the authors' reference files of it, and config, task and msmap files."""
    from terra.config import load_section
    from terra.sim.config import SimConfig, without_distortion
    from terra.sim.dataset import simulate
    from terra.sim.writer import write_dataset

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    seeds = Seeds(root)
    cfg = load_section(None, "sim")
    assert isinstance(cfg, SimConfig)
    cfg = cfg.model_copy(update={"route": cfg.route.model_copy(update={"max_frames": frames})})
    dataset = simulate("tiny", 0, cfg)
    for fmt in ("terra-folder", "semantickitti", "rosbag1", "rosbag2"):
        seeds.datasets[fmt] = write_dataset(dataset, root / fmt, format=fmt, overwrite=True, progress=False)
    write_dataset(
        simulate("tiny", 0, without_distortion(cfg)),
        root / "kitti-raw",
        format="kitti-raw",
        overwrite=True,
        progress=False,
    )
    seeds.datasets["kitti-raw"] = root / "kitti-raw"
    seeds.datasets["rosbag1"] = next((root / "rosbag1").glob("*.bag"))
    seeds.bundle = root / "campus.terra"
    for argv in (
        ["map", root / "terra-folder", "--out", seeds.bundle, "-q"],
        ["build", seeds.bundle, "-q"],
        ["export", seeds.bundle, "-f", "terra-reference", "-o", root / "reference"],
    ):
        code, _, err = cli(argv)
        assert code == 0, err
    seeds.reference = root / "reference"
    seeds.config = root / "config.yaml"
    seeds.config.write_text(
        "\n".join(
            __import__("terra.config", fromlist=["dump_section"]).dump_section(s) for s in ("mapping", "build", "tasks")
        )
    )
    seeds.tasks = root / "tasks.yaml"
    seeds.tasks.write_text(
        "object_tasks:\n  - task: find the dumpster\n  - get bike from the bicycle rack\nalpha: 0.3\n"
        "prediction_method: ms_avg\nregion_tasks:\n  - task: the parking lot\n    place_nodes: [0, 1]\n"
        "k: 2\nterrain_preferences:\n  preferred: [asphalt]\n  forbidden: [water]\n  penalties: {grass: 5}\n"
        "queries:\n  start: 0\n  destination: 3\n"
    )
    seeds.msmap = root / "terra-folder" / "msmap_camera_config.yaml"
    return seeds


# -------------------------------------------------------------------------------------- mutation
def _paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path (tuple of keys / indices) into a parsed JSON / YAML value, the root included."""
    out = [prefix]
    if len(prefix) > 40:  # a nesting bomb added by an earlier edit: not walked into
        return out
    if isinstance(value, dict):
        for k, v in value.items():
            out.extend(_paths(v, prefix + (k,)))
    elif isinstance(value, list):
        for i, v in enumerate(value[:64]):
            out.extend(_paths(v, prefix + (i,)))
    return out


def _interesting_value(rng: random.Random) -> Any:
    choice = rng.randrange(9)
    if choice == 0:
        return rng.choice(INTERESTING_INTS)
    if choice == 1:
        return rng.choice(INTERESTING_FLOATS)
    if choice == 2:
        return rng.choice([None, True, False, "", "x" * rng.choice([1, 300, 5000]), "../../escape", "\u00e9\u2603"])
    if choice == 3:
        return rng.choice([[], {}, [1, 2, 3], {"a": 1}, [None], [[1.5]]])
    if choice == 4:
        nested: Any = 1
        for _ in range(rng.choice([70, 200, 1500])):
            nested = [nested]
        return nested
    if choice == 5:
        return [rng.choice(INTERESTING_FLOATS) for _ in range(rng.choice([2, 3, 4, 9, 12, 16]))]
    if choice == 6:
        return {"unknown_key": rng.choice(INTERESTING_INTS)}
    if choice == 7:
        return rng.random() * rng.choice([1, 100, 1e6]) * rng.choice([1, -1])
    return rng.randrange(-5, 100)


def mutate_structure(value: Any, rng: random.Random) -> Any:
    """One structural edit of a parsed document: replace a value, delete or add a key or element,
    duplicate an element, swap a list for a mapping, or nudge a number."""
    paths = _paths(value)
    path = rng.choice(paths)
    if not path:
        return _interesting_value(rng) if rng.random() < 0.5 else value
    parent = value
    for key in path[:-1]:
        parent = parent[key]
    key, current = path[-1], parent[path[-1]]
    op = rng.randrange(6)
    if op == 0:
        parent[key] = _interesting_value(rng)
    elif op == 1:
        del parent[key]
    elif op == 2 and isinstance(parent, list):
        parent.insert(key, parent[key])
    elif op == 2 and isinstance(parent, dict):
        parent[f"{key}_extra"] = current
    elif op == 3:
        parent[key] = {"0": current} if isinstance(current, list) else [current]
    elif op == 4 and isinstance(current, (int, float)) and not isinstance(current, bool):
        parent[key] = rng.choice(
            [-current, current * 1000 + 1, current - 1, int(current) if abs(current) < float("inf") else 0]
        )
    else:
        parent[key] = _interesting_value(rng)
    return value


def mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    """One to four byte-level edits: flipped bits, interesting integers written over a window,
    truncation, a deleted / inserted / duplicated slice, or garbage."""
    buf = bytearray(data)
    for _ in range(rng.choice([1, 1, 1, 2, 4])):
        n = len(buf)
        op = rng.randrange(8)
        if op == 0 and n:
            i = rng.randrange(n)
            buf[i] ^= 1 << rng.randrange(8)
        elif op == 1 and n >= 8:
            width = rng.choice([1, 2, 4, 8])
            value = rng.choice(INTERESTING_INTS) % (1 << (8 * width))
            i = rng.randrange(n - width + 1)
            buf[i : i + width] = value.to_bytes(width, rng.choice(["little", "big"]))
        elif op == 2:
            del buf[rng.randrange(n + 1) :]
        elif op == 3 and n:
            i = rng.randrange(n)
            del buf[i : i + rng.randrange(1, 256)]
        elif op == 4:
            i = rng.randrange(n + 1)
            buf[i:i] = bytes(rng.randrange(256) for _ in range(rng.choice([1, 7, 64])))
        elif op == 5 and n:
            i = rng.randrange(n)
            buf[i:i] = buf[i : i + rng.randrange(1, 512)]
        elif op == 6 and n:
            i = rng.randrange(n)
            buf[i] = rng.choice([0x00, 0xFF, 0x7F, 0x80, ord("["), ord("{"), ord("-"), ord("\\")])
        else:
            buf = bytearray(rng.choice([b"", b"\xff", b"null", b"[" * 5000, os.urandom(64)]))
    return bytes(buf)


def mutate_text(text: str, rng: random.Random, kind: str) -> bytes:
    """A JSON or YAML document edited structurally (and sometimes at the byte level too)."""
    import yaml

    try:
        value = json.loads(text) if kind == "json" else yaml.safe_load(text)
    except Exception:  # noqa: BLE001 - an already broken seed is mutated as bytes
        value = None
    if value is not None and rng.random() < 0.8:
        for _ in range(rng.choice([1, 1, 2, 3])):
            value = mutate_structure(value, rng)
        try:
            out = (
                json.dumps(value, allow_nan=True) if kind == "json" else yaml.safe_dump(value, sort_keys=False)
            ).encode()
        except (yaml.YAMLError, RecursionError):  # nested past the serialiser: splice deep brackets in as text
            i = rng.randrange(len(text) + 1)
            out = (text[:i] + "[" * 3000 + "]" * 3000 + text[i:]).encode()
        return mutate_bytes(out, rng) if rng.random() < 0.2 else out
    return mutate_bytes(text.encode(), rng)


NPY_DTYPES = [
    "int8",
    "int16",
    "int32",
    "int64",
    "uint8",
    "uint16",
    "uint32",
    "uint64",
    "float16",
    "float32",
    "float64",
    "bool",
    "complex64",
    "<M8[s]",
    "S4",
    ">f4",
    ">i8",
]


def _fit(value: float | int, dtype: np.dtype) -> Any:
    """`value` as an element of `dtype`: integers wrap into its range (as a C cast would)."""
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        return info.min + (int(value) - info.min) % (int(info.max) - int(info.min) + 1)
    if dtype.kind == "b":
        return bool(value)
    return value


def mutate_npy(data: bytes, rng: random.Random) -> bytes:
    """A .npy file edited as an array (dtype, shape, values) or as bytes (header and data)."""
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # casts that overflow are the point
        return _mutate_npy(data, rng)


def _mutate_npy(data: bytes, rng: random.Random) -> bytes:
    op = rng.randrange(6)
    try:
        array = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception:  # noqa: BLE001 - a seed that no longer parses is mutated as bytes
        op = 5
    if op == 0:
        array = array.astype(rng.choice(NPY_DTYPES)) if array.dtype.kind != "M" else array
    elif op == 1:
        shapes = [
            array.reshape(-1),
            array[: rng.randrange(array.shape[0] + 1)] if array.ndim else array,
            array[..., None],
            array.reshape(-1)[:0],
            np.repeat(array, 2, axis=0) if array.ndim else array,
        ]
        array = rng.choice(shapes)
    elif op == 2 and array.size:
        flat = array.reshape(-1).copy()
        for _ in range(rng.choice([1, 3, 50])):
            i = rng.randrange(flat.size)
            flat[i] = _fit(rng.choice(INTERESTING_FLOATS if flat.dtype.kind in "fc" else INTERESTING_INTS), flat.dtype)
        array = flat.reshape(array.shape)
    elif op == 3 and array.size:
        flat = array.reshape(-1).copy()
        rng_np = np.random.default_rng(rng.randrange(2**32))
        rng_np.shuffle(flat)
        array = flat.reshape(array.shape)
    elif op == 4:
        header_end = data.find(b"\n") + 1 or min(len(data), 128)
        header = bytearray(data[:header_end])
        for _ in range(rng.choice([1, 2])):
            if header:
                i = rng.randrange(len(header))
                header[i] = rng.choice(b"0123456789(),'<>|{}:TrueFalse fi ")
        return bytes(header) + data[header_end:]
    if op == 5:
        return mutate_bytes(data, rng)
    buf = io.BytesIO()
    np.save(buf, np.asarray(array), allow_pickle=False)
    return buf.getvalue()


def mutate_file(path: Path, rng: random.Random, outside: Path) -> str:
    """Mutate file `path` in place, choosing how by its suffix; now and then replace it with a folder,
    a FIFO, a link to `outside` or nothing. Returns what was done, in words."""
    roll = rng.random()
    if roll < 0.05:
        path.unlink()
        kind = rng.randrange(4)
        if kind == 0:
            path.mkdir()
            return "replaced by a folder"
        if kind == 1 and hasattr(os, "mkfifo"):
            os.mkfifo(path)
            return "replaced by a FIFO"
        if kind == 2:
            path.symlink_to(outside)
            return "replaced by a link outside"
        return "deleted"
    data = path.read_bytes()
    suffix = path.suffix.lower()
    if suffix == ".npy":
        new = mutate_npy(data, rng)
    elif suffix == ".json":
        new = mutate_text(data.decode("utf-8", "replace"), rng, "json")
    elif suffix in (".yaml", ".yml"):
        new = mutate_text(data.decode("utf-8", "replace"), rng, "yaml")
    else:
        new = mutate_bytes(data, rng)
    path.write_bytes(new)
    return f"{suffix or 'file'} {len(data)} -> {len(new)} bytes"


def resign(bundle: Path, name: str) -> None:
    """Update a bundle manifest's size and SHA-256 of file `name` to its current bytes (when the
    manifest still parses): the mutation is then only caught by content checks."""
    manifest_path = bundle / "manifest.json"
    if (bundle / name).is_symlink() or not (bundle / name).is_file():
        return  # a folder, FIFO or link: the reader must refuse it as it is
    try:
        manifest = json.loads(manifest_path.read_text())
        data = (bundle / name).read_bytes()
        manifest["files"][name] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    except Exception:  # noqa: BLE001 - a manifest or file that is no longer a plain one stays as mutated
        return
    manifest_path.write_text(json.dumps(manifest, allow_nan=True))


# --------------------------------------------------------------------------------------- targets
@dataclass(frozen=True)
class Target:
    """A reader under test. `seed`: which seed to copy ("bundle", a dataset format, "reference",
    "files"); `pick(copy)`: the files that may be mutated; `bundle_file`: mutated files are bundle
    files, re-signed half the time (the manifest then agrees, so only content checks catch them).
    `mutate(path, rng, outside)`: how to mutate a picked file, when not by its suffix (mutate_file).
    The command that reads them comes from `_command`."""

    name: str
    seed: str
    pick: Callable[[Path], list[Path]]
    bundle_file: bool = False
    mutate: Callable[[Path, random.Random, Path], str] | None = None  # default: mutate_file, by suffix


def _bundle_files(pattern: str) -> Callable[[Path], list[Path]]:
    return lambda b: sorted(p for p in b.glob(pattern) if p.is_file() and p.name != "manifest.json")


def _files(pattern: str) -> Callable[[Path], list[Path]]:
    return lambda d: sorted(p for p in d.glob(pattern) if p.is_file())


def _bundle_commands(copy: Path, out: Path, rng_choice: int) -> list:
    commands = [
        ["info", copy],
        ["find", copy, QUERY, "--json"],
        ["find", copy, QUERY, "--method", "3dsg"],
        ["plan", copy, "--from-node", "0", "--to-node", "3"],
        ["monitor", copy, "the parking lot"],
        ["build", copy, "-q"],
        ["find", copy, QUERY, "--save"],
        ["export", copy, "-f", "spark-dsg", "-o", out],
    ]
    return commands[rng_choice % len(commands)]


def _bundle_output(argv: list, copy: Path, out: Path) -> Path | None:
    if argv[0] == "build" or "--save" in argv:
        return copy
    if argv[0] == "export":
        return out
    return None


def _reference_mutator(kind: str) -> Callable[[Path, random.Random, Path], str]:
    """The authors' files mutated as values or renamed (tests/reliability/reference_mutations.py)."""

    def mutate(path: Path, rng: random.Random, outside: Path) -> str:
        from tests.reliability import reference_mutations as rm

        how = rm.mutate_reference_values if kind == "values" else rm.rename_reference_file
        return how(path, rng, outside)

    return mutate


def targets(seeds: Seeds) -> dict[str, Target | Family]:
    """Every reader Terra has, by name, and the value families of tests/reliability/families.py."""
    out = [
        Target("bundle manifest", "bundle", lambda b: [b / "manifest.json"]),
        Target("bundle arrays", "bundle", _bundle_files("**/*.npy"), bundle_file=True),
        Target("scene graph", "bundle", lambda b: [b / "graph" / "scene_graph.json"], bundle_file=True),
        Target("map metadata", "bundle", lambda b: [b / "map" / "meta.json"], bundle_file=True),
        Target("dataset terra-folder", "terra-folder", _files("**/*")),
        Target("dataset semantickitti", "semantickitti", _files("**/*")),
        Target("dataset kitti-raw", "kitti-raw", _files("**/*")),
        Target("bag rosbag1", "rosbag1", _files("*.bag")),
        Target("bag rosbag2", "rosbag2", lambda d: _files("*.mcap")(d) + [d / "metadata.yaml"]),
        Target("config file", "files", lambda f: [f / "config.yaml"]),
        Target("task file", "files", lambda f: [f / "tasks.yaml"]),
        Target("msmap yaml", "terra-folder", lambda d: [d / "msmap_camera_config.yaml"]),
        Target("reference files", "reference", _files("**/*")),
        Target("reference values", "reference", _files("*.p[kt]*"), mutate=_reference_mutator("values")),
        Target(
            "reference names",
            "reference",
            lambda d: _files("gidx2imgs_*")(d) + _files("global_pc/*.npy")(d),
            mutate=_reference_mutator("names"),
        ),
    ]
    return {t.name: t for t in [*out, *families()]}


def _command(target: Target, seeds: Seeds, copy: Path, case: Path, rng: random.Random) -> tuple[list, Path | None]:
    """(argv, output path) for one run of `target` on the mutated copy."""
    out = case / "out"
    name = target.name
    if target.seed == "bundle":
        argv = _bundle_commands(copy, case / "out.dsg.json", rng.randrange(64))
        return argv, _bundle_output(argv, copy, case / "out.dsg.json")
    if name.startswith("dataset") or name.startswith("bag"):
        source = copy / seeds.datasets["rosbag1"].name if name == "bag rosbag1" else copy
        if rng.random() < 0.5:
            return ["inspect", source], None
        return ["map", source, "--out", out, "-q"], out
    if name == "config file":
        argv = rng.choice(
            [
                ["find", case / "bundle", QUERY, "--config", copy / "config.yaml"],
                ["build", case / "bundle", "-q", "--config", copy / "config.yaml"],
            ]
        )
        return argv, (case / "bundle" if argv[0] == "build" else None)
    if name == "task file":
        argv = rng.choice(
            [
                ["find", case / "bundle", "--tasks", copy / "tasks.yaml"],
                ["monitor", case / "bundle", "--tasks", copy / "tasks.yaml"],
                ["plan", case / "bundle", "--tasks", copy / "tasks.yaml"],
            ]
        )
        return argv, None
    if name == "msmap yaml":
        return ["map", copy, "--camera-config", copy / "msmap_camera_config.yaml", "--out", out, "-q"], out
    if name.startswith("reference "):
        return [
            "import",
            copy,
            "-f",
            "terra-reference",
            "-o",
            out,
            "--terrain-classes",
            "sidewalk,grass,asphalt,dirt,water",
        ], out
    raise ValueError(name)


# ------------------------------------------------------------------------------------- judging
def snapshot(root: Path) -> dict[str, tuple]:
    """relative path -> (kind, size, digest of small files / mtime) of everything under `root`."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            rel = str(path.relative_to(root))
            try:
                st = os.lstat(path)
            except FileNotFoundError:
                continue
            if os.path.islink(path) or not (path.is_file() or path.is_dir()):
                out[rel] = ("special", 0, 0)
            elif path.is_dir():
                out[rel] = ("dir", 0, 0)
            else:
                out[rel] = ("file", st.st_size, hashlib.sha256(path.read_bytes()).hexdigest())
    return out


def _valid_output(argv: list, output: Path) -> str | None:
    """Why the result of a successful write is not valid (None when it is)."""
    from terra.bundle import Bundle
    from terra.errors import TerraError

    if argv[0] == "export":
        try:
            json.loads(output.read_text())
        except (OSError, ValueError) as exc:
            return f"export output does not parse: {exc}"
        return None
    try:
        bundle = Bundle(output)
        bundle.verify()
        if "map" in bundle.components:
            from terra.mapping.storage import load_map

            load_map(bundle)
        if "graph" in bundle.components:
            from terra.graph.storage import load_scene_graph

            load_scene_graph(bundle)
    except TerraError as exc:
        return f"written bundle does not load: {exc}"
    return None


class Timeout(BaseException):
    """Past the deadline (a BaseException: no `except Exception` in the code under test hides it)."""


@contextlib.contextmanager
def deadline(seconds: float):
    """Raise Timeout in this (main) thread after `seconds`."""

    def handler(signum, frame):
        raise Timeout(f"no answer within {seconds} s")

    previous = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def run_case(target: Target | Family, seeds: Seeds, rng: random.Random, work: Path, timeout: float = 60.0) -> dict:
    """Mutate a fresh copy of the target's seed with `rng`, run its command in-process and judge it.
    Returns {"target", "mutation", "argv", "code", "outcome", "detail"}; outcome is "ok" (exit 0,
    valid), "refused" (exit 2, one line) or a failure: "traceback", "bad exit code", "not one line",
    "invalid result", "changed bundle", "partial output", "written outside", "hang"."""
    case = work / "case"
    shutil.rmtree(case, ignore_errors=True)
    case.mkdir(parents=True)
    if isinstance(target, Family):
        copy = copy_family_seed(target, seeds, case)
        made = target.make(seeds, copy, case, rng)
    else:
        made = _mutated(target, seeds, case, rng)
    before = snapshot(case)
    result = {
        "target": target.name,
        "mutation": made.mutation,
        "argv": [str(a) for a in made.argv or made.request or []],
        "code": None,
        "outcome": "ok",
        "detail": "",
    }
    if made.request is not None:
        return _run_request(result, made, case, before, timeout)
    argv, output = made.argv or [], made.output
    try:
        with deadline(timeout):
            code, stdout, stderr = cli(argv)
    except Timeout as exc:
        result.update(outcome="hang", detail=str(exc))
        return result
    except BaseException as exc:  # noqa: BLE001 - what escapes `terra.cli.run` is what users see as a traceback
        import traceback

        result.update(outcome="traceback", detail="".join(traceback.format_exception(exc))[-2000:])
        return result
    result["code"] = code
    lines = [line for line in stderr.splitlines() if line.strip()]
    if code not in (0, 2):
        result.update(outcome="bad exit code", detail=stderr[-2000:])
    elif code == 2 and (len(lines) != 1 or not lines[0].startswith("terra: error: ")):
        result.update(outcome="not one line", detail=stderr[-2000:])
    elif code == 2:
        result.update(outcome="refused", detail=lines[0][:300])
    elif output is not None and (output.exists() or output.is_symlink()):
        why = _valid_output(argv, output)
        if why:
            result.update(outcome="invalid result", detail=why)
    result.update(_judge_files(before, snapshot(case), case, output, code))
    return result


def _mutated(target: Target, seeds: Seeds, case: Path, rng: random.Random) -> Made:
    """A copy of the target's seed with one file mutated, and the command that reads it."""
    outside = case.parent / "outside.txt"
    outside.write_text("a file outside the input folder\n")
    copy = _copy_seed(target, seeds, case)
    victim = rng.choice(target.pick(copy))
    mutation = f"{victim.relative_to(copy)}: {(target.mutate or mutate_file)(victim, rng, outside)}"
    if target.bundle_file and rng.random() < 0.5:
        resign(copy, str(victim.relative_to(copy)))
    argv, output = _command(target, seeds, copy, case, rng)
    return Made(mutation, argv, output)


def _run_request(result: dict, made: Made, case: Path, before: dict, timeout: float) -> dict:
    """One HTTP request to a service over the case's bundle copy, judged (see families.judge_response)."""
    assert made.request is not None
    try:
        with deadline(timeout):
            status, text = run_request(case / "bundle", made.request)
    except Timeout as exc:
        result.update(outcome="hang", detail=str(exc))
        return result
    except BaseException as exc:  # noqa: BLE001 - what escapes the service is what a client sees as a 500
        import traceback

        result.update(outcome="traceback", detail="".join(traceback.format_exception(exc))[-2000:])
        return result
    outcome, detail = judge_response(status, text)
    result.update(code=status, outcome=outcome, detail=detail)
    result.update(_judge_files(before, snapshot(case), case, None, 0))
    return result


def _copy_seed(target: Target, seeds: Seeds, case: Path) -> Path:
    if target.seed == "bundle":
        assert seeds.bundle is not None
        return Path(shutil.copytree(seeds.bundle, case / "bundle"))
    if target.seed == "reference":
        assert seeds.reference is not None
        return Path(shutil.copytree(seeds.reference, case / "reference"))
    if target.seed == "files":
        assert seeds.bundle is not None and seeds.config is not None and seeds.tasks is not None
        shutil.copytree(seeds.bundle, case / "bundle")
        (case / "files").mkdir()
        for f in (seeds.config, seeds.tasks):
            shutil.copy(f, case / "files" / f.name)
        return case / "files"
    source = seeds.datasets[target.seed]
    folder = source if source.is_dir() else source.parent
    return Path(shutil.copytree(folder, case / "data"))


def _judge_files(before: dict, after: dict, case: Path, output: Path | None, code: int) -> dict:
    """Changes outside the output path are writes outside it (a staging folder left beside the
    output among them); changes to an input bundle (or to the output bundle when the command
    failed) are changed bundles; anything at the output path of a command that failed is a partial
    output."""
    out_rel = str(output.relative_to(case)) if output is not None else None

    def under(rel: str, top: str | None) -> bool:
        return top is not None and (rel == top or rel.startswith(top + "/"))

    changed = {k for k in set(before) | set(after) if before.get(k) != after.get(k)}
    outside = sorted(k for k in changed if not under(k, out_rel))
    bundle_changes = [k for k in outside if under(k, "bundle")]
    if code != 0:
        bundle_changes += [k for k in changed if under(k, out_rel) and out_rel == "bundle"]
    if bundle_changes:
        return {"outcome": "changed bundle", "detail": ", ".join(bundle_changes[:5])}
    partial = sorted(k for k in changed if under(k, out_rel)) if code != 0 and out_rel != "bundle" else []
    if partial:  # a refused command left (part of) its output
        return {"outcome": "partial output", "detail": ", ".join(partial[:5])}
    if outside:
        return {"outcome": "written outside", "detail": ", ".join(outside[:5])}
    return {}


FAILURES = (
    "traceback",
    "partial output",
    "bad exit code",
    "not one line",
    "invalid result",
    "changed bundle",
    "written outside",
    "hang",
    "crash",
)


# ------------------------------------------------------------------------------------- workers
def supervise(
    jobs: list[dict],
    workers: int,
    timeout: float,
    log: Callable[[dict], None] | None = None,
    until: float | None = None,
) -> list[dict]:
    """Run `jobs` ({"target", "seed", "seeds", "work"}) in `workers` worker processes (`python -m
    tests.reliability.fuzzing worker`, each with its own work folder). A worker that dies mid-job is a crash, one
    that answers nothing for `timeout` seconds a hang (it is killed); either is replaced and the
    jobs go on. No job starts after time.monotonic() `until` (when given): the rest are left out.
    Returns one result per job run, in the order they finish."""
    import selectors
    import subprocess

    pending = list(reversed(jobs))
    results: list[dict] = []
    procs: dict[int, tuple[subprocess.Popen, dict | None, float]] = {}
    selector = selectors.DefaultSelector()
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1", "PYTHONFAULTHANDLER": "0"}
    repo = Path(__file__).resolve().parents[2]

    def start(slot: int) -> None:
        proc = subprocess.Popen(
            [sys.executable, "-m", "tests.reliability.fuzzing", "worker"],
            cwd=repo,
            env=env,
            text=True,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
        )
        procs[slot] = (proc, None, 0.0)
        selector.register(_stdout(proc), selectors.EVENT_READ, slot)
        feed(slot)

    def feed(slot: int) -> None:
        proc = procs[slot][0]
        if pending and (until is None or _now() < until):
            job = dict(pending.pop(), work=str(Path(jobs[0]["work"]) / f"worker{slot}"))
            _stdin(proc).write(json.dumps(job) + "\n")
            _stdin(proc).flush()
            procs[slot] = (proc, job, _now())
        else:
            procs[slot] = (proc, None, 0.0)

    def finish(slot: int, outcome: str, detail: str) -> None:
        proc, job, _ = procs.pop(slot)
        assert job is not None  # a worker is finished while it holds a job
        selector.unregister(_stdout(proc))
        proc.kill()
        proc.wait()
        results.append(
            {
                "target": job["target"],
                "seed": job["seed"],
                "outcome": outcome,
                "detail": detail,
                "mutation": "",
                "argv": [],
                "code": proc.returncode,
            }
        )
        if log:
            log(results[-1])
        start(slot)

    for slot in range(workers):
        start(slot)
    while any(job is not None for _, job, _ in procs.values()):
        for key, _ in selector.select(timeout=1.0):
            slot = key.data
            proc, job, _ = procs[slot]
            line = _stdout(proc).readline()
            if not line:
                finish(slot, "crash", f"worker exited with {proc.wait()}")
                continue
            results.append(json.loads(line))
            if log:
                log(results[-1])
            feed(slot)
        for slot, (_proc, job, since) in list(procs.items()):
            if job is not None and _now() - since > timeout:
                finish(slot, "hang", f"no answer within {timeout} s")
    for proc, _, _ in procs.values():
        _stdin(proc).close()
        proc.wait()
    return results


def _stdin(proc: subprocess.Popen[str]) -> IO[str]:
    assert proc.stdin is not None  # started with stdin=PIPE
    return proc.stdin


def _stdout(proc: subprocess.Popen[str]) -> IO[str]:
    assert proc.stdout is not None  # started with stdout=PIPE
    return proc.stdout


def _now() -> float:
    import time

    return time.monotonic()


def worker() -> None:
    """Answer jobs from stdin (one JSON line each) with results on stdout (one JSON line each)."""
    import resource

    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    limit = 6 << 30  # an allocation a size check missed fails here instead of taking the machine
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    real_stdout = sys.stdout
    cache: dict[str, tuple[Seeds, dict[str, Target | Family]]] = {}
    for line in sys.stdin:
        job = json.loads(line)
        key = json.dumps(job["seeds"], sort_keys=True)
        if key not in cache:
            seeds = Seeds.from_json(job["seeds"])
            cache[key] = (seeds, targets(seeds))
        seeds, table = cache[key]
        rng = random.Random(f"{job['target']}/{job['seed']}")
        # The worker's own deadline answers before the supervisor's: a hang the alarm can break is
        # reported with what was running; one it cannot (a C loop) is found by the supervisor.
        result = run_case(table[job["target"]], seeds, rng, Path(job["work"]), job.get("timeout", 60.0) * 0.8)
        result["seed"] = job["seed"]
        real_stdout.write(json.dumps(result) + "\n")
        real_stdout.flush()


if __name__ == "__main__":
    if sys.argv[1:] == ["worker"]:
        worker()
    elif sys.argv[1:2] == ["seeds"]:
        print(json.dumps(build_seeds(Path(sys.argv[2])).to_json()))
    else:
        sys.exit("usage: python -m tests.reliability.fuzzing worker | seeds FOLDER")
