"""Sensors agree with each other and with the ground truth on the tiny simulated campus."""

import numpy as np
import pytest

from terra.geometry import invert_pose, project_points, transform_points

FRAMES = (3, 18, 21, 33)
SOLID = {
    "car",
    "dumpster",
    "building",
    "trash can",
    "mailbox",
}  # convex enough that the centre is seen through the body


@pytest.fixture(scope="module")
def frames(tiny_campus):
    return [tiny_campus[i] for i in FRAMES]


def test_camera_synchronised_with_scan(frames):
    for f in frames:
        assert len(f.cameras) == 1
        cam = f.cameras[0]
        assert cam.stamp == f.stamp
        assert cam.image.shape == (480, 640, 3) and cam.image.dtype == np.uint8
        assert cam.semantic.shape == cam.instance.shape == (480, 640)


def test_projected_object_centres_land_in_their_instance_masks(tiny_campus, frames):
    gt = {o.instance_id: o for o in tiny_campus.ground_truth().objects}
    checked = inside = 0
    for f in frames:
        cam = f.cameras[0]
        cal = cam.calibration
        T_cam_map = cal.T_cam_lidar @ invert_pose(f.T_map_lidar)
        cam_pos = invert_pose(T_cam_map)[:3, 3]
        ids, counts = np.unique(cam.instance[cam.instance > 0], return_counts=True)
        for iid, n in zip(ids, counts):
            obj = gt[int(iid)]
            if obj.class_name not in SOLID or n < 300:
                continue
            uv, valid = project_points(transform_points(T_cam_map, obj.center[None]), cal)
            if not valid[0]:
                continue
            u, v = np.round(uv[0]).astype(int)
            checked += 1
            seen = cam.instance[v, u]
            if seen == iid:
                inside += 1
                assert cam.semantic[v, u] == obj.class_id
            else:
                # Only something nearer the camera may hide the centre.
                assert seen > 0, f"centre of {obj.class_name} {iid} shows sky/terrain"
                occluder = gt[int(seen)]
                assert (
                    np.linalg.norm(occluder.center - cam_pos)
                    < np.linalg.norm(obj.center - cam_pos) + max(occluder.size) / 2
                )
    assert checked >= 10
    assert inside >= 5  # the rest are hidden by nearer cars in the rows, checked above


def test_lidar_point_labels_match_the_pixels_they_project_to(frames):
    agree = total = 0
    for f in frames:
        cam = f.cameras[0]
        cal = cam.calibration
        pc = transform_points(cal.T_cam_lidar, f.points.astype(np.float64))
        uv, valid = project_points(pc, cal)
        idx = np.flatnonzero(valid)
        px = np.round(uv[idx]).astype(int)
        # z-buffer: the nearest point per pixel is the one the camera can see.
        order = np.lexsort((pc[idx, 2], px[:, 1] * cal.width + px[:, 0]))
        key = (px[:, 1] * cal.width + px[:, 0])[order]
        first = np.ones(len(order), bool)
        first[1:] = key[1:] != key[:-1]
        sel = idx[order[first]]
        u, v = px[order[first], 0], px[order[first], 1]
        # Skip label edges, where a few millimetres of viewpoint difference change the answer.
        inner = (u > 0) & (v > 0) & (u < cal.width - 1) & (v < cal.height - 1)
        sel, u, v = sel[inner], u[inner], v[inner]
        sem = cam.semantic
        flat = np.ones(len(sel), bool)
        for du in (-1, 0, 1):
            for dv in (-1, 0, 1):
                flat &= sem[v + dv, u + du] == sem[v, u]
        labels, pix = f.point_labels[sel[flat]], sem[v[flat], u[flat]]
        agree += int((labels == pix).sum())
        total += int(flat.sum())
        inst_ok = f.point_instances[sel[flat]] == cam.instance[v[flat], u[flat]]
        assert inst_ok.mean() > 0.95
    assert total > 3000
    assert agree / total > 0.97


def test_point_labels_and_instances_match_ground_truth(tiny_campus, frames):
    gt = {o.instance_id: o for o in tiny_campus.ground_truth().objects}
    terrain_ids = {c.id for c in tiny_campus.classes.terrain_classes}
    for f in frames:
        inst = f.point_instances
        assert set(np.unique(f.point_labels[inst == 0])) <= terrain_ids  # terrain has no instance
        for iid in np.unique(inst[inst > 0]):
            assert set(np.unique(f.point_labels[inst == iid])) == {gt[int(iid)].class_id}
            # Points of an object lie in (a slightly grown) ground-truth box.
            obj = gt[int(iid)]
            p = transform_points(f.T_map_lidar, f.points[inst == iid].astype(np.float64)) - obj.center
            c, s = np.cos(obj.yaw), np.sin(obj.yaw)
            local = np.stack([c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1], p[:, 2]], 1)
            assert np.all(np.abs(local) <= obj.size / 2 + 1e-3)  # float32 points


def test_ground_points_lie_on_the_ground_truth_height(tiny_campus, frames):
    raster = tiny_campus.ground_truth().terrain
    for f in frames:
        terrain = f.point_instances == 0
        p = transform_points(f.T_map_lidar, f.points[terrain].astype(np.float64))
        inside = raster.class_at(p[:, :2]) >= 0
        # Ground-truth heights are sampled at cell centres; slopes of a few degrees over half a cell.
        np.testing.assert_allclose(p[inside, 2], raster.height_at(p[inside, :2]), atol=0.03)
        assert np.mean(raster.class_at(p[inside, :2]) == f.point_labels[terrain][inside]) > 0.98
