"""Typed contracts of the structured files Terra reads, checked at the boundary (DESIGN.md decision 13).

`read_model(path, Model)` reads a JSON or YAML file safely (terra.fileio) and validates it; every
failure is one line naming the file and the first bad field (validation_message).
Past this point code may trust types, ranges and finiteness.

Two rules for unknown keys: files Terra writes (bundle manifest, map metadata, scene graph) accept
keys they do not know, so a bundle written by a newer version of the same schema still opens; files
people write (dataset class tables, calibrations, configs, task files) refuse them, so a misspelt
key is named instead of silently ignored. Values are strict (no "3" for 3, no true for 1) and
floats finite.

Models here: the bundle manifest (`BundleManifest`: file entries whose names must stay inside the
bundle, the embedder, terrain classes, components), the map metadata (`MapMeta`), the scene-graph
document (`SceneGraphDocument`, spark_dsg's JSON with Terra's metadata), and the dataset documents
(`ClassesFile`, `CalibrationDoc`, `TerraDatasetFile`, `CamerasFile`). Config sections
(terra.config) and task files (terra.tasks.task_file) are pydantic models of their own modules and
are read through `read_model` too.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from terra.errors import TerraError

M = TypeVar("M", bound=BaseModel)

MAX_CLASS_ID = 65535  # label images are 16-bit PNGs; SemanticKITTI keeps class = label & 0xFFFF
MAX_IMAGE_SIDE = 65535  # pixels (JPEG's limit)
MAX_EMBEDDING_DIM = 65536
MAX_REGION_LEVELS = 8  # region level chars 'R'..'Y' (terra.graph.storage)


def validation_message(source: str, exc: ValidationError) -> str:
    """One line naming the first bad field and what was expected."""
    err = exc.errors()[0]
    where = ".".join(str(p) for p in err["loc"]) or "(root)"
    return f"{source}: field '{where}': {err['msg']}"


def validate_model(data: Any, model: type[M], source: str | Path) -> M:
    """`model` from already parsed `data`; TerraError naming `source` and the first bad field."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise TerraError(validation_message(str(source), exc)) from None
    except RecursionError:
        raise TerraError(f"{source}: nested too deeply") from None


def read_model(path: str | Path, model: type[M], what: str | None = None) -> M:
    """The JSON (.json) or YAML (any other suffix) file `path` as `model` (see the module docstring)."""
    from terra.fileio import read_json, read_yaml

    path = Path(path)
    what = what or f"{model.__name__} file"
    data = read_json(path, what) if path.suffix.lower() == ".json" else read_yaml(path, what)
    return validate_model({} if data is None and path.suffix.lower() != ".json" else data, model, path)


# ---------------------------------------------------------------------------------- value types
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
PositiveFloat = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
Count = Annotated[int, Field(ge=0, le=2**62)]
Vec3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]
NonEmptyStr = Annotated[str, Field(min_length=1, max_length=4096)]
_SEGMENT = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.+-]{0,127}$")


def bundle_file_name(name: str) -> str:
    """A file name of a bundle's manifest: a relative POSIX path whose every part is a plain name
    (no '..', no hidden or absolute parts), ending in .npy or .json, so it resolves inside the bundle."""
    parts = name.split("/")
    if len(parts) > 8 or not all(_SEGMENT.match(p) for p in parts) or not name.endswith((".npy", ".json")):
        raise ValueError(f"file name {name[:80]!r} must be a relative path of plain names ending in .npy or .json")
    if name == "manifest.json":
        raise ValueError("the manifest cannot list itself")
    return name


def _unique(values: list[str]) -> list[str]:
    if len(set(values)) != len(values):
        raise ValueError("names must be unique")
    return values


BundleFileName = Annotated[str, AfterValidator(bundle_file_name)]
UniqueNames = Annotated[list[NonEmptyStr], AfterValidator(_unique)]


class Strict(BaseModel):
    """Base of every model of what people write (config sections, task files, requests, dataset
    documents): unknown keys are refused, so a misspelt key is named; floats are finite."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Section(Strict):
    """Base of every config section (terra.config hands them out): values are also validated on
    assignment."""

    model_config = ConfigDict(validate_assignment=True)


class _Written(BaseModel):
    """A document Terra writes: strict values, unknown keys kept (a newer writer's additions)."""

    model_config = ConfigDict(extra="allow", strict=True, allow_inf_nan=False)


class _Authored(Strict):
    """A document people write, with strict values (no "3" for 3)."""

    model_config = ConfigDict(strict=True)


# ------------------------------------------------------------------------------------ the bundle
class FileEntry(Strict):
    model_config = ConfigDict(strict=True)

    bytes: Count
    sha256: Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]


class EmbedderInfo(_Written):
    name: NonEmptyStr
    dim: Annotated[int, Field(ge=1, le=MAX_EMBEDDING_DIM)]


class Wgs84Anchor(_Written):
    """components.map.wgs84_anchor: where the map frame lies on the Earth. Map origin (0, 0, 0) is
    at latitude `lat`, longitude `lon` (degrees, WGS84) and height `alt` (metres, the source's
    datum); the map's +x axis points `yaw_deg` counter-clockwise from east, +z up. `projection`
    says which plane the map's metres are: 'tmerc' a transverse Mercator centred on the origin
    (local east/north metres), 'kitti-mercator' the KITTI devkit's spherical Mercator scaled by
    cos(lat) (the plane its OXTS poses are in). `source` says where the anchor came from."""

    lat: Annotated[float, Field(ge=-90.0, le=90.0)]
    lon: Annotated[float, Field(ge=-180.0, le=180.0)]
    alt: FiniteFloat = 0.0
    yaw_deg: FiniteFloat = 0.0
    projection: Literal["tmerc", "kitti-mercator"] = "tmerc"
    source: str = ""


class MapComponent(_Written):
    """components.map: counts of the stored map (checked against the arrays), config and stats."""

    points: Count | None = None
    bank: Count | None = None
    images: Count | None = None
    observations: Count | None = None
    observed_points: Count | None = None
    dataset: dict[str, Any] | None = None  # the source it was mapped from (terra.datasets.fingerprint)
    # Every source fused into the map, in order: a first `terra map` and each `--append` or live
    # session ({name, fingerprint, frames, first_frame}).
    sources: list[dict[str, Any]] | None = None
    frames: Count | None = None  # frames offered to the fusion so far (the next frame's index)
    time_span: Annotated[list[float], Field(min_length=2, max_length=2)] | None = None  # first, last fused stamp, s
    version: Count | None = None  # the bundle version that last changed the map
    wgs84_anchor: Wgs84Anchor | None = None  # the map frame on the Earth, when the source knew it
    # Rows per chunk of a live version's per-point arrays (terra/mapping/chunks.py); None: the flat layout.
    chunk_rows: Count | None = None
    config: dict[str, Any] = Field(default_factory=dict)
    stats: dict[str, Any] = Field(default_factory=dict)


class GraphStats(_Written):
    """The parts of components.graph.stats that `terra info` shows."""

    places_per_terrain: dict[str, Count] = Field(default_factory=dict)
    edges: dict[str, Count] = Field(default_factory=dict)
    embedding_source: dict[str, Count] = Field(default_factory=dict)
    embedding_rule: str | None = None


class GroundInfo(_Written):
    """components.graph.ground: the ground layers of the build (terra.graph.ground), arrays
    graph/ground_<name> with one row per observed cell of a grid of `shape` (H, W) cells of
    `cell_size` metres, whose cell (0, 0) is cell `offset` (row, col) of the grid whose lower-left
    corner lies at `origin` (x, y metres, map frame); `units` says what each array holds, in which
    unit (height m; gradient dz/dx, dz/dy; step m; roughness m); `edge_geometry` names the columns
    of graph/place_edge_geometry (step_m, rise_deg, fall_deg, unobserved_m, cross_deg; bundles
    written before unobserved_m or cross_deg was recorded name the first three or four)."""

    origin: Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)]
    cell_size: PositiveFloat
    offset: Annotated[list[Count], Field(min_length=2, max_length=2)]
    shape: Annotated[list[Count], Field(min_length=2, max_length=2)]
    observed_cells: Count
    units: dict[str, str] = Field(default_factory=dict)
    edge_geometry: list[str] = Field(default_factory=list)


class GraphComponent(_Written):
    """components.graph: format, counts of the stored scene graph, config and stats."""

    format: int | None = None
    places: Count | None = None
    place_edges: Count | None = None
    regions: Annotated[list[Count], Field(max_length=MAX_REGION_LEVELS)] | None = None
    objects: Count | None = None
    config: dict[str, Any] = Field(default_factory=dict)
    stats: GraphStats = Field(default_factory=GraphStats)
    map_version: Count | None = None  # the map version the graph was built on (stale when older)
    ground: GroundInfo | None = None  # the ground layers, when the build made them


class Components(_Written):
    map: MapComponent | None = None
    graph: GraphComponent | None = None


class BundleManifest(_Written):
    """manifest.json (schema and schema_version are checked before, with their own messages)."""

    schema_: Literal["terra-bundle"] = Field(alias="schema")
    schema_version: int
    written_by: str | None = None
    # Counts the committed versions of this bundle: each write based on the previous version adds
    # one, so a reader can tell which snapshot it answered from.
    version: Count | None = None
    files: dict[BundleFileName, FileEntry] = Field(default_factory=dict)
    embedder: EmbedderInfo | None = None
    terrain_classes: UniqueNames = Field(default_factory=list)
    components: Components = Field(default_factory=Components)
    perception: dict[str, Any] | None = None


class ClassRow(_Authored):
    """One class of a dataset's table (classes.json, map/meta.json)."""

    id: Annotated[int, Field(ge=0, le=MAX_CLASS_ID)]
    name: NonEmptyStr
    terrain: bool = False
    semantickitti_id: Annotated[int, Field(ge=0, le=MAX_CLASS_ID)] | None = None


class MapMeta(_Written):
    """map/meta.json."""

    format: int = 1
    voxel_size: PositiveFloat = 0.4
    visibility_cell_size: PositiveFloat | None = None
    camera_names: list[str] = Field(default_factory=list)
    dataset: str = ""
    classes: list[ClassRow] = Field(default_factory=list)


# ------------------------------------------------------------------------------- the scene graph
NodeId = Annotated[int, Field(ge=0, lt=2**64)]


class BoundingBox(_Written):
    dimensions: Annotated[list[Annotated[float, Field(ge=0.0, allow_inf_nan=False)]], Field(min_length=3, max_length=3)]
    world_P_center: Vec3


class NodeAttributes(_Written):
    type: str
    position: Vec3
    name: str | None = None
    semantic_label: int | None = None
    distance: FiniteFloat | None = None
    bounding_box: BoundingBox | None = None
    metadata: dict[str, Any] = Field(default_factory=dict)


class GraphNode(_Written):
    id: NodeId
    layer: int
    attributes: NodeAttributes


class EdgeInfo(_Written):
    weight: Annotated[float, Field(ge=0.0, allow_inf_nan=False)] = 1.0
    metadata: dict[str, Any] = Field(default_factory=dict)


class GraphEdge(_Written):
    source: NodeId
    target: NodeId
    info: EdgeInfo = Field(default_factory=EdgeInfo)


class GraphMeta(_Written):
    format: int
    terrain_classes: Annotated[UniqueNames, Field(min_length=1)]
    embedder: str = ""
    region_method: str = ""
    region_levels: Annotated[int, Field(ge=0, le=MAX_REGION_LEVELS)]
    next_id: dict[str, Count] = Field(default_factory=dict)  # per NodeSymbol char (format 2)


class GraphMetadata(_Written):
    terra: GraphMeta


class SceneGraphDocument(_Written):
    """graph/scene_graph.json: spark_dsg's JSON with Terra's metadata (terra.graph.storage)."""

    metadata: GraphMetadata
    nodes: list[GraphNode]
    edges: list[GraphEdge]


class ObjectTerra(_Written):
    """metadata.terra of an object node."""

    yaw: FiniteFloat
    score: FiniteFloat
    point_count: Count
    place: Count


class EdgeTerra(_Written):
    """metadata.terra of a place-place edge."""

    kind: Literal["gvd", "cross_terrain", "bridge", "level_route"]


# --------------------------------------------------------------------------------- dataset files
class ClassesFile(_Authored):
    """classes.json of a dataset folder."""

    classes: Annotated[list[ClassRow], Field(min_length=1)]


Row3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]
Row4 = Annotated[list[FiniteFloat], Field(min_length=4, max_length=4)]


class CalibrationDoc(_Authored):
    """One exact camera calibration (terra_dataset.json, terra_cameras.json): K 3x3 pixels, dist in
    OpenCV order for `model`, T_cam_lidar 4x4 (LiDAR -> camera optical frame, metres)."""

    model_config = ConfigDict(strict=False)  # ints read as floats

    name: NonEmptyStr
    width: Annotated[int, Field(ge=1, le=MAX_IMAGE_SIDE, strict=True)]
    height: Annotated[int, Field(ge=1, le=MAX_IMAGE_SIDE, strict=True)]
    K: Annotated[list[Row3], Field(min_length=3, max_length=3)]
    dist: Annotated[list[FiniteFloat], Field(max_length=14)] = Field(default_factory=list)
    T_cam_lidar: Annotated[list[Row4], Field(min_length=4, max_length=4)]
    model: str = "pinhole"


class TerraDatasetFile(_Written):
    """terra_dataset.json of a terra-folder dataset (Terra writes it; people may edit it)."""

    format: str | None = None
    version: int | None = None
    name: NonEmptyStr | None = None
    frames: Count | None = None
    first_camera: Annotated[int, Field(ge=0, le=1)] | None = None
    cameras: list[CalibrationDoc] | None = None


class CamerasFile(_Authored):
    """terra_cameras.json of a SemanticKITTI sequence written by Terra."""

    cameras: list[CalibrationDoc]


class ReferenceSidecar(_Written):
    """Terra's sidecar beside the authors' map files it exports (terra.interop.reference_export):
    what `terra import` needs and their files do not say."""

    embedder: EmbedderInfo | None = None
    stored_dim: Annotated[int, Field(ge=1, le=MAX_EMBEDDING_DIM)] | None = None  # vector width in the files
    visibility_pairs: Count | None = None  # rows of terra_visibility.npy
    image_poses: list[Annotated[list[FiniteFloat], Field(min_length=12, max_length=12)]] | None = None
    terrain_classes: UniqueNames | None = None
    camera_names: list[str] | None = None
    voxel_size: PositiveFloat | None = None
    visibility_cell_size: PositiveFloat | None = None


class GroundTruthObject(_Written):
    instance_id: int
    class_id: Annotated[int, Field(ge=0, le=MAX_CLASS_ID)]
    class_name: str
    center: Vec3
    size: Annotated[list[Annotated[float, Field(ge=0.0, allow_inf_nan=False)]], Field(min_length=3, max_length=3)]
    yaw: FiniteFloat


class GroundTruthObjects(_Written):
    """ground_truth/objects.json (terra.datasets.ground_truth)."""

    objects: list[GroundTruthObject]


class GroundTruthTerrain(_Written):
    """ground_truth/terrain.json: the raster's lower-left corner (metres), cell size, legend."""

    origin: Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)]
    resolution: PositiveFloat
    legend: dict[Annotated[str, Field(pattern=r"^[0-9]{1,5}$")], str]


class GroundTruthRegion(_Written):
    name: str
    description: str
    polygon: Annotated[list[Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)]], Field(min_length=3)]


class GroundTruthRegions(_Written):
    """ground_truth/regions.json."""

    regions: list[GroundTruthRegion]


# ------------------------------------------------------------------------------- ROS 2 bag folders
class _Nanoseconds(_Written):
    nanoseconds: Count


class _StartTime(_Written):
    nanoseconds_since_epoch: Annotated[int, Field(ge=-(2**62), le=2**62)]


class RosbagTopicMetadata(_Written):
    name: NonEmptyStr
    type: NonEmptyStr
    serialization_format: str
    offered_qos_profiles: str | list[Any] = ""


class RosbagTopicCount(_Written):
    topic_metadata: RosbagTopicMetadata
    message_count: Count


class RosbagFileInfo(_Written):
    path: NonEmptyStr
    starting_time: _StartTime
    duration: _Nanoseconds
    message_count: Count


class RosbagInfo(_Written):
    version: Annotated[int, Field(ge=1, le=1000)]
    storage_identifier: NonEmptyStr
    relative_file_paths: Annotated[list[NonEmptyStr], Field(min_length=1)]
    duration: _Nanoseconds
    starting_time: _StartTime
    message_count: Count
    topics_with_message_count: list[RosbagTopicCount]
    compression_format: str = ""
    compression_mode: str = ""
    files: list[RosbagFileInfo] | None = None
    custom_data: dict[str, str] | None = None
    ros_distro: str | None = None


class RosbagMetadata(_Written):
    """metadata.yaml of a ROS 2 bag folder (rosbag2's format, versions 1 and up), checked before
    the bag reader trusts it."""

    rosbag2_bagfile_information: RosbagInfo
