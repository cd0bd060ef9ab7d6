"""`terra inspect`: what a source holds (frames, time span, cameras as read, pose source, what
would be skipped), and for a bag its topics, TF tree and a ready-to-edit dataset section."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from terra.cli import app
from terra.words import counted


def _camera_lines(cam: dict) -> list[str]:
    K = cam["K"]
    T = cam["T_cam_lidar"]
    return [
        f"  camera {cam['name']}: {cam['width']} x {cam['height']}, fx {K[0][0]:.3f} fy {K[1][1]:.3f} "
        f"cx {K[0][2]:.3f} cy {K[1][2]:.3f}, {cam['model']} lens, dist {cam['dist']}",
        "    T_cam_lidar: " + " | ".join(" ".join(f"{v:.6f}" for v in row) for row in T[:3]),
    ]


def _bag_lines(d: dict) -> list[str]:
    import yaml

    lines = [
        f"  storage: {d['storage']}, {d['duration_s']:.3f} s recorded ({d['start']:.3f} .. {d['end']:.3f})",
        "  topics:",
    ]
    width = max([len(r["topic"]) for r in d["topics"]] + [5])
    for r in d["topics"]:
        rate = f"{r['rate_hz']:.2f} Hz" if r["rate_hz"] else "-"
        span = f"{r['first']:.3f} .. {r['last']:.3f} s" if r["first"] is not None else "no messages"
        lines.append(f"    {r['topic']:<{width}}  {r['type']:<32} {r['count']:>7}  {rate:>10}  {span}")
    lines.append("  TF tree:" if d["tf"] else "  TF tree: none")
    for e in d["tf"]:
        kind = "static" if e["static"] else f"dynamic, {e['samples']} samples"
        lines.append(f"    {e['parent']} -> {e['child']} ({kind})")
    if "lidar" in d:
        fields = ", ".join(f"{f['name']}@{f['offset']}" for f in d["lidar"]["fields"])
        lines.append(f"  LiDAR: {d['lidar']['topic']} in frame {d['lidar']['frame']}, fields {fields}")
    if d.get("problem"):
        lines.append(f"  cannot map as is: {d['problem']}")
    if "dataset" in d:
        lines.append("  dataset section (paste into a config file, edit, pass with --config):")
        lines += ["    " + line for line in yaml.safe_dump({"dataset": d["dataset"]}, sort_keys=False).splitlines()]
    return lines


def render(info: dict) -> list[str]:
    span = info["time_span"]
    lines = [
        f"{info['path']} ({info['format']}): {counted(info['frames'], 'frame')}"
        + (f", {span[0]:.3f} .. {span[1]:.3f} s ({span[1] - span[0]:.3f} s)" if span else ""),
        f"  poses: {info['pose_source']}",
    ]
    for cam in info["cameras"]:
        lines += _camera_lines(cam)
    if not info["cameras"]:
        lines.append("  cameras: none")
    for name, count in info["skipped"].items():
        note = info["skipped_notes"].get(name)
        lines.append(f"  would skip {name}: {count}" + (f" (first: {note})" if note else ""))
    details = info["details"]
    if "topics" in details:
        lines += _bag_lines(details)
    else:
        lines += [f"  {k}: {v}" for k, v in details.items()]
    return lines


@app.command("inspect")
def inspect_command(
    source: Path = typer.Argument(..., help="A dataset folder, a ROS bag (.bag, .mcap, ROS 2 bag folder)."),
    format: str = typer.Option("auto", "--format", help="auto, terra-folder, semantickitti, kitti-raw or rosbag."),
    config: Path | None = typer.Option(
        None, "--config", "-c", help="YAML config whose `dataset` section sets the loader's options."
    ),
    poses: str = typer.Option(
        "auto",
        "--poses",
        help="auto: the source's own poses (said to be missing when it has none); odometry: describe it as "
        "`terra map --poses odometry` reads it (without its own poses).",
    ),
    as_json: bool = typer.Option(False, "--json", help="Print everything as one JSON document."),
) -> None:
    """Show what a dataset or ROS bag holds before mapping it.

    Show what SOURCE holds before mapping it: frames and time span, each camera's size,
    intrinsics, lens model and coefficients and T_cam_lidar as read, the pose source, and what
    would be skipped and why. For a bag also every topic (type, count, rate, span), the TF tree,
    and a ready-to-edit `dataset` config section.

    Example: terra inspect drive.bag --json

    Example (a source without poses of its own): terra inspect drive.bag --poses odometry
    """
    from terra.config import TerraConfig
    from terra.datasets.describe import describe_source, source_json
    from terra.errors import TerraError
    from terra.odometry.kiss import POSE_MODES

    if poses not in POSE_MODES:
        raise TerraError(f"--poses {poses!r}: expected one of: {', '.join(POSE_MODES)}")
    mode = "odometry" if poses == "odometry" else "source"
    info = source_json(describe_source(source, format, TerraConfig.read(config).dataset, mode))
    if as_json:
        typer.echo(json.dumps(info, indent=1, sort_keys=True))
    else:
        typer.echo("\n".join(render(info)))
