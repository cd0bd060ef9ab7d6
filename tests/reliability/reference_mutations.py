"""Mutations of the authors' metric-semantic map files as values rather than bytes (tests/reliability/fuzzing.py).

A byte edit of a pickle mostly breaks its opcodes; the families that once escaped `terra import` as
tracebacks are well-formed files holding values of the wrong kind: integers past 64 bits as keys,
indices or counts (OverflowError), NaN, infinite or huge ranges (ValueError), numpy scalars and
containers where numbers belong (TypeError), image names whose camera or stamp do not fit, tensors
of the wrong dtype, shape or values, and file names whose numbers are not numbers (an image range
of `nan` metres). These mutators load Terra's own export (the seed: plain data, so plain pickle
and torch.load are safe on it), change one to three values and write the file back in the
authors' format, or rename a file.
"""

from __future__ import annotations

import io
import pickle
import random
from pathlib import Path
from typing import Any

import numpy as np

BIG_INTS = [2**62 + 1, 2**63, 2**63 - 1, 2**64, 2**64 + 1, -(2**63) - 1, 10**30, 10**400, -1, -(10**20)]
ODD_FLOATS = [float("nan"), float("inf"), float("-inf"), 1e308, -1e-300, -0.0, 1.5, -3.25]


def _odd_numpy() -> list[Any]:
    return [
        np.int64(-1),
        np.uint64(2**64 - 1),
        np.int8(-5),
        np.float64("nan"),
        np.float32("inf"),
        np.float16(2.5),
        np.bool_(True),
        np.complex64(1 + 2j),
        np.datetime64(1, "s"),
    ]


def odd_key(rng: random.Random) -> Any:
    """A hashable value that is no valid index."""
    return rng.choice(
        [*BIG_INTS, *ODD_FLOATS, *_odd_numpy(), "7", "", None, True, b"3", 1 + 1j, (1, 2), frozenset([1])]
    )


def odd_value(rng: random.Random) -> Any:
    """Any value: a wrong number, a wrong container, a huge or odd name."""
    return rng.choice(
        [
            odd_key(rng),
            set(),
            {},
            [],
            {odd_key(rng)},
            {0: odd_key(rng)},
            [odd_key(rng)],
            np.arange(3),
            np.array([np.nan, np.inf]),
            np.zeros((2, 2), np.uint64),
            "camera99999999999999999999_images/cam99999999999999999999_img_1.000000.jpg",
            "camera1_images/cam1_img_" + "9" * 400 + ".jpg",
            "camera0_images/cam0_img_1.000000.jpg",
            "camera1_images/cam2_img_1.000000.jpg",
            "x" * 5000,
        ]
    )


def _edit(value: Any, rng: random.Random, depth: int = 0) -> Any:
    """One edit somewhere in `value` (a dict, list, set or leaf); returns the edited value."""
    if isinstance(value, dict) and value and depth < 3:
        key = rng.choice(list(value))
        op = rng.randrange(4)
        if op == 0:  # a bad key for an existing value
            value[odd_key(rng)] = value.pop(key)
        elif op == 1:  # a bad value under an existing key
            value[key] = odd_value(rng)
        elif op == 2:  # a new entry
            value[odd_key(rng)] = odd_value(rng) if rng.random() < 0.5 else value[key]
        else:  # an edit inside the value
            value[key] = _edit(value[key], rng, depth + 1)
        return value
    if isinstance(value, list) and value and depth < 3:
        i = rng.randrange(len(value))
        value[i] = odd_value(rng) if rng.random() < 0.6 else _edit(value[i], rng, depth + 1)
        return value
    if isinstance(value, (set, frozenset)) and depth < 3:
        items = set(value)
        if items and rng.random() < 0.5:
            items.discard(rng.choice(sorted(items, key=repr)))
        items.add(odd_key(rng))
        return items
    return odd_value(rng)


def mutate_pickle(path: Path, rng: random.Random) -> str:
    with open(path, "rb") as f:
        value = pickle.load(f)  # the seed is Terra's own export: plain data
    edits = rng.choice([1, 1, 2, 3])
    for _ in range(edits):
        value = _edit(value, rng)
    protocol = rng.choice([2, 4, 5])
    path.write_bytes(pickle.dumps(value, protocol=protocol))
    return f"pickle: {edits} value edit(s), protocol {protocol}"


def mutate_tensor(path: Path, rng: random.Random) -> str:
    """A torch file with another dtype, shape or values (NaN, infinity, huge), or not a tensor."""
    import torch

    tensor = torch.load(path, weights_only=True)
    op = rng.randrange(6)
    if op == 0:
        dtype = rng.choice([torch.float16, torch.float64, torch.int64, torch.uint8, torch.bool, torch.complex64])
        tensor, what = tensor.to(dtype), f"dtype {dtype}"
    elif op == 1:
        shapes = [tensor.reshape(-1), tensor[None], tensor[:0], tensor[:, :1], tensor[:, :-7], tensor.T]
        tensor = rng.choice(shapes)
        what = f"shape {tuple(tensor.shape)}"
    elif op == 2 and tensor.numel():
        flat = tensor.reshape(-1).clone()
        for _ in range(rng.choice([1, 5, 100])):
            flat[rng.randrange(flat.numel())] = rng.choice([float("nan"), float("inf"), -float("inf"), 1e38, 0.0])
        tensor, what = flat.reshape(tensor.shape), "odd values"
    elif op == 3:
        tensor, what = torch.zeros_like(tensor), "all zeros"
    elif op == 4 and tensor.ndim == 2:
        extra = torch.ones(tensor.shape[0], rng.choice([1, 128]))
        tensor, what = torch.cat([tensor, extra], dim=1), "non-zero columns added"
    else:
        buffer = io.BytesIO()
        torch.save(rng.choice([[tensor], {"bank": tensor}, 3, (tensor, tensor)]), buffer)
        path.write_bytes(buffer.getvalue())
        return "torch file: a container, not a tensor"
    torch.save(tensor, path)
    return f"torch file: {what}"


def mutate_reference_values(path: Path, rng: random.Random, outside: Path) -> str:
    """The authors' pickle or torch file `path` with odd values (see the module docstring)."""
    if path.suffix == ".pkl":
        return mutate_pickle(path, rng)
    if path.suffix == ".pt":
        return mutate_tensor(path, rng)
    raise ValueError(f"not one of the authors' pickle or torch files: {path}")


ODD_NUMBER_TEXTS = ["nan", "inf", "-inf", "-20.0", "0", "0.0", "1e999", "1e-400", "twenty", "", "20.0.0", "9" * 200]


def rename_reference_file(path: Path, rng: random.Random, outside: Path) -> str:
    """Rename an image-range file (gidx2imgs_{thr}m_dict) or the global map (global_pc_{t}.npy) so
    the number in its name is not a usable number."""
    text = rng.choice(ODD_NUMBER_TEXTS)
    if path.name.startswith("gidx2imgs_"):
        new = path.with_name(f"gidx2imgs_{text}m_dict_{path.name.split('m_dict_', 1)[1]}")
    else:
        new = path.with_name(f"global_pc_{text}.npy")
    path.rename(new)
    return f"renamed to {new.name[:80]}"
