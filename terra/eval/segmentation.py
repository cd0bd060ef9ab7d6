"""Table I: a terrain segmenter against the dataset's labelled images.

Ground truth per pixel is the terrain index of the image's semantic label (terrain classes of the
dataset's ClassTable, in id order), or "not terrain". The segmenter sees each image with the same
noise generator the mapping pipeline gave it (seeded by [seed, frame, camera]), so the table
measures the segmentation that went into the map.
"""

from __future__ import annotations

import time

import numpy as np

from terra.datasets.base import ClassTable, Dataset
from terra.errors import TerraError
from terra.eval.metrics.segmentation import SegmentationScores, confusion_matrix, segmentation_scores
from terra.perception.base import TerrainSegmenter
from terra.progress import progress


def terrain_truth(semantic: np.ndarray, classes: ClassTable) -> np.ndarray:
    """(H, W) terrain index per pixel of a semantic image; len(terrain classes) = not terrain."""
    terrain = classes.terrain_classes
    lut = np.full(max(c.id for c in classes) + 1, len(terrain), dtype=np.int64)
    for i, c in enumerate(terrain):
        lut[c.id] = i
    ids = np.asarray(semantic, dtype=np.int64)
    return lut[np.where((ids >= 0) & (ids < lut.size), ids, 0)]


def sample_frames(n_frames: int, max_images: int, cameras: int) -> np.ndarray:
    """Frame indices evenly spread over the dataset so that about `max_images` images are used."""
    wanted = max(1, int(np.ceil(max_images / max(cameras, 1))))
    if n_frames <= wanted:
        return np.arange(n_frames)
    return np.unique(np.linspace(0, n_frames - 1, wanted).round().astype(np.int64))


def evaluate_segmenter(
    segmenter: TerrainSegmenter, dataset: Dataset, max_images: int = 40, seed: int = 0, show_progress: bool = True
) -> SegmentationScores:
    """Confusion of `segmenter` against ground truth on up to `max_images` labelled images.

    FPS counts segmenter wall time only, after one untimed warm-up image (models load lazily); a
    segmenter whose `timed` attribute is False (the labels lookup) gets no FPS."""
    names = [c.name for c in dataset.classes.terrain_classes]
    if list(segmenter.terrain_classes) != names:
        raise TerraError(
            f"segmenter terrain classes {list(segmenter.terrain_classes)} differ from the dataset's {names}"
        )
    timed = bool(getattr(segmenter, "timed", True))
    n_labels = len(names) + 1
    total = np.zeros((n_labels, n_labels), dtype=np.int64)
    seconds, images, warm = 0.0, 0, not timed
    first = dataset[0]
    frames = sample_frames(len(dataset), max_images, len(first.cameras))
    for i in progress(frames, desc="segmentation", enabled=show_progress, unit="frames"):
        frame = dataset[int(i)]
        for c, camera in enumerate(frame.cameras):
            if camera.semantic is None or images >= max_images:
                continue
            if not warm:
                segmenter.segment_terrain(camera, np.random.default_rng([seed, int(i), c]))
                warm = True
            rng = np.random.default_rng([seed, int(i), c])
            start = time.perf_counter()
            predicted = np.asarray(segmenter.segment_terrain(camera, rng), dtype=np.int64)
            seconds += time.perf_counter() - start
            predicted = np.where(predicted < 0, len(names), predicted)
            total += confusion_matrix(terrain_truth(camera.semantic, dataset.classes), predicted, n_labels)
            images += 1
    if images == 0:
        raise TerraError(f"dataset {dataset.name!r} has no labelled camera images to evaluate terrain segmentation on")
    return segmentation_scores(total, names, seconds, images, timed)


def terrain_table(
    dataset: Dataset,
    segmenters: dict[str, tuple[TerrainSegmenter, int]],
    max_images: int = 40,
    show_progress: bool = True,
) -> dict:
    """Table I for several segmenters on the same labelled images: {"dataset", "images", "methods":
    {label: scores}}; `segmenters` maps a row label to (segmenter, noise seed)."""
    methods = {}
    for label, (segmenter, seed) in segmenters.items():
        methods[label] = evaluate_segmenter(segmenter, dataset, max_images, seed, show_progress).to_json()
    images = next(iter(methods.values()))["images"] if methods else 0
    return {"dataset": dataset.name, "images": images, "methods": methods}
