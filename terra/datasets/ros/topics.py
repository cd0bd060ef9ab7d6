"""Which topics of a bag to read: the LiDAR cloud, each camera's image, camera_info and label
images, and an odometry topic. Explicit choices are checked; missing ones are found when the bag
makes them unambiguous, else a TerraError lists the candidates to put in the `dataset` section."""

from __future__ import annotations

from dataclasses import dataclass, field

from terra.datasets.ros.bag import Bag
from terra.errors import TerraError

CLOUD = ("sensor_msgs/msg/PointCloud2",)
IMAGE = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
RAW_IMAGE = ("sensor_msgs/msg/Image",)
INFO = ("sensor_msgs/msg/CameraInfo",)
ODOMETRY = ("nav_msgs/msg/Odometry",)
TF = ("tf2_msgs/msg/TFMessage",)
NOT_COLOUR = ("semantic", "instance", "label", "labels", "depth", "mask")  # image names that are no colour image
# Preferred colour image names under a camera namespace, best first (raw before compressed: exact pixels).
PREFERRED = (
    "image_raw",
    "image_color",
    "image_rect_color",
    "image",
    "image_raw/compressed",
    "image_color/compressed",
    "image_rect_color/compressed",
    "image/compressed",
)


@dataclass
class CameraTopics:
    """One camera: its name, colour image topic, camera_info topic and optional label images."""

    name: str
    image: str
    info: str
    semantic: str | None = None
    instance: str | None = None


@dataclass
class TopicChoice:
    lidar: str
    cameras: list[CameraTopics] = field(default_factory=list)
    odometry: str | None = None


def namespace(topic: str) -> str:
    return topic.rsplit("/", 1)[0]


def choose_lidar(bag: Bag, topic: str | None) -> str:
    if topic is not None:
        return bag.require(topic, CLOUD, "LiDAR")
    clouds = bag.topics_of_type(*CLOUD)
    if len(clouds) == 1:
        return clouds[0]
    if not clouds:
        raise TerraError(f"{bag.path}: no sensor_msgs/PointCloud2 topic; topics: {', '.join(bag.topics) or 'none'}")
    raise TerraError(
        f"{bag.path}: {len(clouds)} PointCloud2 topics ({', '.join(clouds)}); set dataset.lidar_topic to one of them"
    )


def camera_for_info(bag: Bag, info: str, name: str | None = None, image: str | None = None) -> CameraTopics:
    """The camera whose camera_info topic is `info`: its colour image (given, or the one image
    topic beside it) and `semantic` / `instance` label images beside it when present."""
    ns = namespace(info)
    name = name or ns.strip("/").replace("/", "_") or "camera"
    beside = [t for t in bag.topics_of_type(*IMAGE) if t.startswith(ns + "/")]
    if image is None:
        colour = [t for t in beside if t[len(ns) + 1 :].split("/")[0] not in NOT_COLOUR]
        ranked = sorted(
            colour, key=lambda t: PREFERRED.index(t[len(ns) + 1 :]) if t[len(ns) + 1 :] in PREFERRED else len(PREFERRED)
        )
        known = [t for t in ranked if t[len(ns) + 1 :] in PREFERRED]
        if len(colour) == 1 or known:
            image = (known or colour)[0]
        else:
            choices = ", ".join(colour) or "none"
            raise TerraError(
                f"{bag.path}: camera_info {info}: cannot tell which image topic is its colour image "
                f"(candidates: {choices}); set dataset.cameras[].image_topic"
            )
    else:
        bag.require(image, IMAGE, f"camera {name} image")
    labels = {
        kind: f"{ns}/{kind}"
        for kind in ("semantic", "instance")
        if bag.topics.get(f"{ns}/{kind}") and bag.topics[f"{ns}/{kind}"].msgtype in RAW_IMAGE
    }
    return CameraTopics(name, image, info, labels.get("semantic"), labels.get("instance"))


def choose_cameras(bag: Bag, configured: list | None) -> list[CameraTopics]:
    """Configured cameras (each checked), or one per CameraInfo topic that has a colour image beside it."""
    if configured is not None:
        out = []
        for n, cam in enumerate(configured):
            image = bag.require(cam.image_topic, IMAGE, f"camera {n} image")
            info = cam.info_topic or f"{namespace(image.removesuffix('/compressed'))}/camera_info"
            if info not in bag.topics:
                infos = ", ".join(bag.topics_of_type(*INFO)) or "none"
                raise TerraError(
                    f"{bag.path}: camera {cam.name or n}: no camera_info topic '{info}' for image {image} "
                    f"(CameraInfo topics: {infos}); set dataset.cameras[{n}].info_topic"
                )
            bag.require(info, INFO, f"camera {n} camera_info")
            chosen = camera_for_info(bag, info, cam.name, image)
            if cam.semantic_topic:
                chosen.semantic = bag.require(cam.semantic_topic, RAW_IMAGE, f"camera {n} semantic labels")
            if cam.instance_topic:
                chosen.instance = bag.require(cam.instance_topic, RAW_IMAGE, f"camera {n} instance labels")
            out.append(chosen)
        return out
    cameras = []
    for info in bag.topics_of_type(*INFO):
        ns = namespace(info)
        if any(t.startswith(ns + "/") for t in bag.topics_of_type(*IMAGE)):
            cameras.append(camera_for_info(bag, info))
    return cameras


def choose_odometry(bag: Bag, topic: str | None) -> str | None:
    """The nav_msgs/Odometry topic: the configured one (checked), else the only one, else None."""
    if topic is not None:
        return bag.require(topic, ODOMETRY, "odometry poses")
    found = bag.topics_of_type(*ODOMETRY)
    return found[0] if len(found) == 1 else None
