import numpy as np
import pytest

from asg.io.pcd import read_pcd, write_pcd


def test_pcd_round_trip_with_open3d(tmp_path):
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(500, 4)).astype(np.float32)
    path = tmp_path / "c.pcd"
    write_pcd(path, pts)
    assert np.array_equal(read_pcd(path), pts)
    cloud = o3d.t.io.read_point_cloud(str(path))
    assert np.allclose(cloud.point.positions.numpy(), pts[:, :3])
    assert np.allclose(cloud.point.intensity.numpy().ravel(), pts[:, 3])
