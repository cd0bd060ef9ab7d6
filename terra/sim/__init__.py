"""The simulated outdoor campus: procedural world, ray-cast LiDAR and cameras, ground truth.

from terra.sim import simulate, write_dataset
ds = simulate("small", seed=0)      # a Dataset; frames render on demand
frame = ds[0]; gt = ds.ground_truth()
write_dataset(ds, "campus-small", format="terra-folder")
"""

from terra.sim.config import CameraConfig, LidarConfig, RouteConfig, SimConfig
from terra.sim.dataset import SimDataset, simulate
from terra.sim.writer import write_dataset

__all__ = ["simulate", "SimDataset", "SimConfig", "LidarConfig", "CameraConfig", "RouteConfig", "write_dataset"]
