"""What evaluation reads: an opened bundle (map, graph, query embedder), the dataset it was mapped
from and that dataset's ground truth, with the checks that they belong together (by content)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

from terra.bundle import Bundle
from terra.datasets.base import Dataset
from terra.datasets.ground_truth import GroundTruth, load_ground_truth
from terra.errors import TerraError
from terra.graph.scene_graph import SceneGraph
from terra.loaded import LoadedBundle
from terra.mapping.semantic_map import MetricSemanticMap
from terra.perception.text import TextEmbedder


def mapped_dataset_name(bundle: Bundle) -> str:
    """Name of the dataset a bundle's map was built from ("" when not recorded)."""
    if not bundle.has("map/meta.json"):
        return ""
    meta = bundle.json("map/meta.json")
    return str(meta.get("dataset", "")) if isinstance(meta, dict) else ""


def mapped_dataset_fingerprint(bundle: Bundle) -> str:
    """Content fingerprint of the dataset a bundle's map was built from (terra.datasets.fingerprint;
    "" for bundles made before it was recorded)."""
    map_info = bundle.model.components.map
    source = map_info.dataset if map_info is not None else None
    return str(source.get("fingerprint") or "") if isinstance(source, dict) else ""


def check_same_dataset(bundle: Bundle, dataset: Dataset, gt_root: Path) -> str:
    """The fingerprint of `dataset` when it is the one `bundle` was mapped from; TerraError when
    it is not. Recognised by content (a copied or renamed dataset is the same one); bundles
    without a recorded fingerprint fall back on the recorded name."""
    from terra.datasets.fingerprint import dataset_fingerprint

    recorded = mapped_dataset_fingerprint(bundle)
    found = dataset_fingerprint(dataset)
    if recorded and recorded != found:
        raise TerraError(
            f"{gt_root}: not the dataset {bundle.path} was mapped from (its frames differ from those of "
            f"{mapped_dataset_name(bundle) or 'the mapped dataset'!r})"
        )
    mapped = mapped_dataset_name(bundle)
    if not recorded and mapped and mapped != dataset.name:
        raise TerraError(
            f"{gt_root}: dataset {dataset.name!r} is not the one {bundle.path} was mapped from ({mapped!r})"
        )
    return found


@dataclass
class EvalInputs:
    """What evaluation reads: the loaded bundle (map, graph, query embedder) and the ground truth."""

    loaded: LoadedBundle
    gt: GroundTruth
    gt_root: Path
    hierarchies: dict[str, tuple[SceneGraph, float | None]] = field(default_factory=dict)

    dataset: Dataset | None = None
    dataset_name: str = ""
    dataset_fingerprint: str = ""

    def fingerprint_record(self) -> dict[str, str]:
        """{"fingerprint": ...} of the evaluated dataset, for files that name it (tuned.json)."""
        return {"fingerprint": self.dataset_fingerprint} if self.dataset_fingerprint else {}

    @property
    def bundle(self) -> Bundle:
        return self.loaded.bundle

    @property
    def msm(self) -> MetricSemanticMap:
        return self.loaded.msm

    @property
    def graph(self) -> SceneGraph:
        return self.loaded.require_graph("evaluation")

    @property
    def embedder(self) -> TextEmbedder:
        return self.loaded.embedder

    @classmethod
    def load(cls, bundle_path: str | Path, gt_root: str | Path, loaded: LoadedBundle | None = None) -> EvalInputs:
        """Open everything, cheapest checks first, so bad input fails before any work: the bundle
        must hold a scene graph, `gt_root` must be a dataset written by `terra sim`, and it must
        be the dataset the bundle was mapped from (by its content, check_same_dataset). `loaded`:
        an already opened bundle to share (its map, graph and embedder are not loaded again)."""
        loaded = loaded or LoadedBundle(bundle_path)
        loaded.require_graph("evaluation")
        dataset, gt = dataset_ground_truth(Path(gt_root))
        found = check_same_dataset(loaded.bundle, dataset, Path(gt_root))
        loaded.require_map("evaluation")
        loaded.embedder  # noqa: B018 (loaded now: evaluation embeds many texts)
        return cls(loaded, gt, Path(gt_root), dataset=dataset, dataset_name=dataset.name, dataset_fingerprint=found)

    @property
    def objects_only(self) -> bool:
        """Whether the ground truth has objects alone (real datasets such as KITTI)."""
        return self.gt.terrain is None

    def hierarchy(self, method: str) -> tuple[SceneGraph, float | None]:
        """The scene graph with `method` region levels on the bundle's places, and the seconds
        it took to build them (cached)."""
        if method not in self.hierarchies:
            from terra.eval.regions import rebuild_regions

            self.hierarchies[method] = rebuild_regions(self.bundle, self.graph, method)
        return self.hierarchies[method]


def dataset_ground_truth(gt_root: Path) -> tuple[Dataset, GroundTruth]:
    """The dataset at `gt_root` and its ground truth: the simulator's ground_truth/ folder, or the
    dataset's own (KITTI labels: objects only)."""
    from terra.datasets import open_dataset
    from terra.datasets.ground_truth import GROUND_TRUTH_DIR
    from terra.datasets.registry import detect_format

    if (gt_root / GROUND_TRUTH_DIR).is_dir() or detect_format(gt_root) is None:
        gt = load_ground_truth(gt_root)  # names the missing folder when there is neither
        return open_dataset(gt_root), gt
    dataset = open_dataset(gt_root)
    if not isinstance(dataset, _WithGroundTruth):
        raise TerraError(f"{gt_root}: no ground truth ({GROUND_TRUTH_DIR}/ or labels) in this dataset")
    return dataset, dataset.ground_truth()


@runtime_checkable
class _WithGroundTruth(Protocol):
    """A dataset that carries its own ground truth (KITTI labels, a Terra folder, a bag)."""

    def ground_truth(self) -> GroundTruth: ...
