"""One simulated drive written as a folder and as a ROS 2 bag maps to the same map, once the one
input the bag cannot carry is left out: the folder's global map (global_pc/, the authors' layout).

With a global map, fusion associates each scan point with the nearest global-map point within the
gate (as the reference does); without one, with its own voxel of the accumulated map. On the tiny
campus, seed 3, the global map is exactly the accumulated voxel centroids (68,133 points both), but
135,570 of 773,230 scan points (17.5 %) are nearer another voxel's centroid than their own, which
gives 7,639 points with object observations from the folder and 7,525 from the bag.
"""

from __future__ import annotations

import numpy as np

from terra.cli import run

SAME = ("points.npy", "counts_data.npy", "counts_indices.npy", "counts_indptr.npy", "bank.npy", "ms_max_id.npy")


def test_folder_and_bag_of_one_drive_map_alike_without_the_folder_global_map(sim_sources, tmp_path, capsys):
    config = tmp_path / "no-global-map.yaml"
    config.write_text("mapping:\n  fusion:\n    use_global_map: false\n")
    bag, folder = tmp_path / "bag.terra", tmp_path / "folder.terra"
    assert run(["map", str(sim_sources["rosbag2"]), "--out", str(bag), "-q"]) == 0
    assert run(["map", str(sim_sources["terra-folder"]), "--out", str(folder), "-q", "--config", str(config)]) == 0
    for name in SAME:
        assert (bag / "map" / name).read_bytes() == (folder / "map" / name).read_bytes(), name
    # T_cam_lidar differs by 2.2e-16 (the bag's comes through /tf_static, the folder's through its
    # own quaternion file), which may move a LiDAR point across a pixel edge: a vote at most.
    votes = [np.load(b / "map" / "terrain_votes.npy").astype(np.int64) for b in (bag, folder)]
    assert np.abs(votes[0] - votes[1]).sum() <= 2
    with_global = tmp_path / "with.terra"
    assert run(["map", str(sim_sources["terra-folder"]), "--out", str(with_global), "-q"]) == 0
    assert (with_global / "map" / "points.npy").read_bytes() == (bag / "map" / "points.npy").read_bytes()
