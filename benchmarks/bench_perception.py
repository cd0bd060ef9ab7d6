"""Phase 1 perception cost per frame, by stage, at realistic sizes, with random-weight models.

Models (built once into --models, random weights; no real weights exist here):
- CLIP with the ViT-B/16 architecture (224 px, patch 16, 12 x 768 vision layers, 512-d), saved with
  save_pretrained and run by the `clip` embedder;
- a YOLO-seg nano-sized network (terrain, 3 classes) and a FastSAM-s-sized one (YOLOv8s-seg, 1 class),
  plain torch exported with torch.onnx (benchmarks/yolo_nets.py) and run by the `yolo-onnx` runtime.

Per 640 x 480 frame (the simulator's camera, its LiDAR scan for fusion):
- terrain: letterbox + onnxruntime of the nano network, then decoding and painting of 4 terrain masks;
- masks: letterbox + onnxruntime of the FastSAM-s network, then decoding of 30 masks;
- embeddings: CLIP of the 30 masked crops (batched) and of the whole image;
- fusion: association and per-image fusion of those outputs into a map (MapFusion).
Random weights give degenerate detections, so decoding runs on synthetic outputs of the same shapes
with realistic content (30 boxes of 20-200 px, smooth prototype fields); inference runs on the
networks themselves. Also: the 30 crops embedded one at a time by the same embedder (target: batched
>= 3x faster on the CPU), and, for reference, one at a time through transformers' CLIPProcessor.

Usage:
  python benchmarks/bench_perception.py                  # full (several minutes on 2 cores)
  python benchmarks/bench_perception.py --quick          # tiny models: checks the script runs
Writes benchmarks/results/perception.json (perception-quick.json with --quick) and prints a table.
There is no GPU on the project's machine; with --device cuda the same table is measured on a GPU.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from benchtable import report  # noqa: E402

TERRAIN = ["sidewalk", "grass", "asphalt"]
T = TypeVar("T")


def build_models(folder: Path, quick: bool) -> dict:
    """The three models (reused when already built)."""
    import yolo_nets

    from tests.perception.models import save_clip

    folder.mkdir(parents=True, exist_ok=True)
    clip = folder / ("clip-tiny" if quick else "clip-vit-b-16-random")
    if not (clip / "model.safetensors").is_file():
        if quick:
            save_clip(clip)
        else:
            save_clip(
                clip,
                image_size=224,
                patch_size=16,
                hidden=768,
                layers=12,
                heads=12,
                projection_dim=512,
                text_hidden=512,
                text_heads=8,
            )
    info: dict[str, Path | dict] = {"clip": clip}
    for role, size, names in (("terrain", "nano", TERRAIN), ("masks", "small", ["object"])):
        path = folder / f"yolo-seg-{size}{'-320' if quick else ''}.onnx"
        imgsz = (320, 320) if quick else (640, 640)
        if not path.is_file():
            info[f"{role}_net"] = yolo_nets.export(path, names, size, imgsz)
        else:
            import torch

            depth, width = yolo_nets.SIZES[size]
            net = yolo_nets.YoloSeg(len(names), depth, width)
            info[f"{role}_net"] = {
                "params_m": sum(p.numel() for p in net.parameters()) / 1e6,
                "gflops": yolo_nets.conv_gflops(net.eval(), imgsz),
                "bytes": path.stat().st_size,
            }
            del torch
        info[role] = path
    return info


def synthetic_outputs(nc: int, boxes: list[tuple[float, float, float, float, int]], shape: tuple[int, int], seed: int):
    """output0 (1, 4 + nc + 32, 8400) with one anchor per (cx, cy, w, h, class) box (input pixels) and
    smooth random prototypes (1, 32, H/4, W/4), so masks are blobs filling about half their boxes."""
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    out = np.zeros((1, 4 + nc + 32, 8400), np.float32)
    for i, (cx, cy, w, h, cls) in enumerate(boxes):
        out[0, :4, i] = cx, cy, w, h
        out[0, 4 + cls, i] = 0.5 + 0.4 * rng.random()
        out[0, 4 + nc :, i] = rng.normal(size=32)
    mh, mw = shape[0] // 4, shape[1] // 4
    protos = ndimage.gaussian_filter(rng.normal(size=(32, mh, mw)), sigma=(0, 4, 4))
    protos /= protos.std()
    return out, protos[None].astype(np.float32)


def object_boxes(n: int, seed: int) -> list[tuple[float, float, float, float, int]]:
    """n boxes of 20-200 px (input pixels of a 640 x 640 letterbox of a 640 x 480 image: rows 80..560)."""
    rng = np.random.default_rng(seed)
    w, h = rng.uniform(20, 200, n), rng.uniform(20, 200, n)
    cx, cy = rng.uniform(w / 2, 640 - w / 2), rng.uniform(80 + h / 2, 560 - h / 2)
    return [(float(a), float(b), float(c), float(d), 0) for a, b, c, d in zip(cx, cy, w, h)]


def median_time(fn: Callable[[], T], repeats: int) -> tuple[float, T]:
    """Median wall-clock seconds of `repeats` (at least one) calls, and the last call's result."""
    times: list[float] = []
    result = _timed_call(fn, times)
    for _ in range(repeats - 1):
        result = _timed_call(fn, times)
    return statistics.median(times), result


def _timed_call(fn: Callable[[], T], times: list[float]) -> T:
    start = time.perf_counter()
    result = fn()
    times.append(time.perf_counter() - start)
    return result


def scene_frame():
    """Frame 3 of the tiny simulated campus: a 640 x 480 image and its LiDAR scan."""
    from terra.sim import simulate

    dataset = simulate("tiny", seed=0)
    return dataset, dataset[3]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--quick", action="store_true", help="tiny models, few repeats (checks the script)")
    parser.add_argument(
        "--models", type=Path, default=Path("/tmp/terra-bench-models"), help="folder of the built models"
    )
    parser.add_argument("--masks", type=int, default=30, help="object masks per frame")
    parser.add_argument("--repeats", type=int, default=3, help="runs per stage (median)")
    parser.add_argument("--pairs", type=int, default=2, help="alternating batched / one-at-a-time CLIP runs (median)")
    parser.add_argument("--device", default="cpu", help="cpu, cuda, auto")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's own choice)")
    parser.add_argument("--result", type=Path, default=None)
    args = parser.parse_args()
    repeats = 1 if args.quick else args.repeats

    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    from terra.mapping.config import MappingConfig
    from terra.mapping.fusion import MapFusion
    from terra.perception.base import ImagePerception
    from terra.perception.clip import ClipEmbedder
    from terra.perception.device import resolve_device
    from terra.perception.masks import MaskSet
    from terra.perception.models import blank_terrain, paint_terrain
    from terra.perception.onnx_yolo import OnnxSegmentationModel
    from terra.perception.yolo import DecodeSettings, decode

    load_start = os.getloadavg()[0]
    device = resolve_device(args.device)
    models = build_models(args.models, args.quick)
    dataset, frame = scene_frame()
    camera = frame.cameras[0]
    image = np.asarray(camera.image)
    rows: list[tuple[str, str, str]] = []
    result: dict = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "device": device.torch,
        "fp16": device.fp16,
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": load_start,
        "quick": args.quick,
        "image": list(image.shape[:2]),
    }

    # Terrain: network inference, then decoding of 4 terrain masks.
    terrain_net = OnnxSegmentationModel(models["terrain"], device, "terrain", "terrain")
    masks_net = OnnxSegmentationModel(models["masks"], device, "masks", "masks")
    for net in (terrain_net, masks_net):
        net.run(image)  # session start-up and first-run allocation are not per-frame costs
    t_terrain_net, (_, _, box) = median_time(lambda: terrain_net.run(image), repeats)
    insz = terrain_net.input_shape
    scale = insz[0] / 640
    terrain_boxes = [
        (160 * scale, 440 * scale, 320 * scale, 240 * scale, 0),
        (480 * scale, 440 * scale, 320 * scale, 240 * scale, 1),
        (320 * scale, 500 * scale, 200 * scale, 120 * scale, 2),
        (600 * scale, 380 * scale, 80 * scale, 80 * scale, 1),
    ]
    t_out0, t_protos = synthetic_outputs(3, terrain_boxes, insz, seed=1)
    class_to_terrain = np.arange(3, dtype=np.int16)
    t_terrain_decode, terrain = median_time(
        lambda: paint_terrain(decode(t_out0, t_protos, 3, box, DecodeSettings(conf=0.25, iou=0.7)), class_to_terrain),
        repeats,
    )

    # Masks: network inference, then decoding of the object masks.
    t_masks_net, (_, _, mbox) = median_time(lambda: masks_net.run(image), repeats)
    boxes = [(a * scale, b * scale, c * scale, d * scale, k) for a, b, c, d, k in object_boxes(args.masks, seed=2)]
    m_out0, m_protos = synthetic_outputs(1, boxes, masks_net.input_shape, seed=3)
    settings = DecodeSettings(conf=0.003, iou=0.9, max_det=100, min_pixels=50, agnostic=True)
    t_masks_decode, found = median_time(lambda: decode(m_out0, m_protos, 1, mbox, settings), repeats)
    masks = MaskSet(found.shape, found.mask_boxes, list(found.mask_crops))
    t_blank, view = median_time(lambda: blank_terrain(image, terrain, 3), repeats)

    # Embeddings: batched, then one at a time, alternating so that the machine's load drifts equally
    # over both (the ratio is the median of the pairs); transformers' processor one at a time once.
    clip = ClipEmbedder(models["clip"], device, batch_size=32)
    single = ClipEmbedder(models["clip"], device, batch_size=1)
    crops = clip.mask_crops(view, masks)
    clip.embed_crops(crops[:2])
    single.embed_crops(crops[:1])
    t_crops, _ = median_time(lambda: clip.mask_crops(view, masks), repeats)
    pairs = []
    mask_vectors = single_vectors = None
    for _ in range(args.pairs):
        t_b, mask_vectors = median_time(lambda: clip.embed_crops(crops), 1)
        t_s, single_vectors = median_time(lambda: single.embed_crops(crops), 1)
        pairs.append((t_b, t_s))
    if mask_vectors is None or single_vectors is None:
        raise SystemExit("--pairs must be at least 1")
    t_batched = statistics.median(b for b, _ in pairs)
    t_single = statistics.median(s for _, s in pairs)
    ratio = statistics.median(s / b for b, s in pairs)
    t_image, image_vector = median_time(lambda: clip.embed_crops([image])[0], repeats)
    t_processor = processor_one_at_a_time(clip, crops)

    # Fusion of this frame's outputs into a map.
    seen = ImagePerception(terrain, masks, mask_vectors, image_vector)
    config = MappingConfig()

    def fuse():
        fusion = MapFusion(config, TERRAIN, clip.dim, None)
        points_map, index = fusion.associate(frame.points, frame.T_map_lidar)
        fusion.integrate_image(
            frame.points, points_map, index, frame.T_map_lidar, camera.calibration, camera.stamp, seen
        )
        return fusion

    t_fusion, _ = median_time(fuse, repeats)

    n = len(masks)
    stages = {
        "terrain (nano YOLO-seg inference)": t_terrain_net,
        "terrain (decode + paint 4 masks)": t_terrain_decode,
        "masks (FastSAM-s inference)": t_masks_net,
        f"masks (decode {n} masks)": t_masks_decode,
        "terrain removal": t_blank,
        f"embeddings ({n} masked crops)": t_crops,
        f"embeddings (CLIP, {n} crops batched)": t_batched,
        "embeddings (CLIP, whole image)": t_image,
        "fusion (associate + integrate)": t_fusion,
    }
    total = sum(stages.values())
    for name, seconds in stages.items():
        rows.append((name, f"{seconds * 1e3:.1f} ms", ""))
    rows.append(("total per frame (one camera)", f"{total * 1e3:.0f} ms", "<= 100 ms on a GPU (not measurable here)"))
    rows.append((f"CLIP {n} crops one at a time (same embedder)", f"{t_single * 1e3:.0f} ms", ""))
    rows.append((f"CLIP {n} crops batched vs one at a time", f"{ratio:.2f}x", ">= 3x on the CPU"))
    rows.append(
        (
            f"CLIP {n} crops one at a time via CLIPProcessor",
            f"{t_processor * 1e3:.0f} ms",
            f"{t_processor / t_batched:.2f}x the batched time",
        )
    )
    max_diff = float(np.abs(single_vectors - mask_vectors).max())
    rows.append(("batched vs single max |difference|", f"{max_diff:.1e}", "same vectors"))
    result.update(
        {
            "stages_ms": {k: round(v * 1e3, 3) for k, v in stages.items()},
            "total_ms": round(total * 1e3, 3),
            "masks": n,
            "clip_single_ms": round(t_single * 1e3, 3),
            "clip_batched_ms": round(t_batched * 1e3, 3),
            "batched_speedup": round(ratio, 3),
            "clip_pairs_s": [[round(b, 3), round(t, 3)] for b, t in pairs],
            "clip_processor_single_ms": round(t_processor * 1e3, 3),
            "batched_vs_single_max_abs_diff": max_diff,
            "networks": {k: v for k, v in models.items() if k.endswith("_net")},
            "repeats": repeats,
            "load_average_1min_at_end": os.getloadavg()[0],
        }
    )
    for role in ("terrain", "masks"):
        net = models.get(f"{role}_net")
        if net:
            rows.append((f"{role} network", f"{net['params_m']:.2f} M params, {net['gflops']:.1f} GFLOPs", ""))
    out = args.result or ROOT / "benchmarks" / "results" / (
        "perception-quick.json" if args.quick else "perception.json"
    )
    report(rows, result, out)


def processor_one_at_a_time(clip, crops: list[np.ndarray]) -> float:
    """Seconds to embed `crops` one by one with transformers' CLIPProcessor (PIL preprocessing)."""
    import torch
    from transformers import CLIPProcessor

    processor = CLIPProcessor.from_pretrained(str(clip.folder))
    start = time.perf_counter()
    with torch.inference_mode():
        for crop in crops:
            pixels = processor(images=[crop], return_tensors="pt")["pixel_values"].to(clip.device.torch)
            clip._model.get_image_features(pixel_values=pixels.to(clip._dtype))
    return time.perf_counter() - start


if __name__ == "__main__":
    main()
