"""The simulated outdoor campus: procedural world, ray-cast LiDAR and cameras, ground truth.

    from terra.sim import simulate
    ds = simulate("small", seed=0)      # a Dataset; frames render on demand
    frame = ds[0]; gt = ds.ground_truth()
"""

from terra.sim.config import CameraConfig, LidarConfig, RouteConfig, SimConfig
from terra.sim.dataset import SimDataset, simulate

__all__ = ["simulate", "SimDataset", "SimConfig", "LidarConfig", "CameraConfig", "RouteConfig", "write_dataset"]


def write_dataset(dataset, out, format: str = "terra-folder", overwrite: bool = False, progress: bool = True):
    """Write `dataset` to folder `out` as 'terra-folder' or 'semantickitti' (see terra.sim.writer)."""
    from terra.sim.writer import write_dataset as _write

    return _write(dataset, out, format=format, overwrite=overwrite, progress=progress)
