"""Importers: rosbag2 recordings (written here with rosbags from synthetic messages) and SKIPP's layout."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from spade.annotate import annotate
from spade.annotation.importers.rosbag import RosbagImportError
from spade.annotation.importers.skipp import SkippImportError
from annotation_support import check_dataset, small_cfg

RES = 0.1
SIZE = 64


def world() -> np.ndarray:
    """OccupancyGrid values (row 0 = lowest y) of a 12 m x 10 m site with a wall, origin (0, 0)."""
    v = np.zeros((100, 120), np.int8)
    v[[0, -1], :] = 100
    v[:, [0, -1]] = 100
    v[60:62, 10:80] = 100  # a wall north of the route
    v[80:99, 100:119] = -1  # unexplored corner
    return v


def trajectory() -> np.ndarray:
    """An L drive: east along y=3 then a 90 degree left turn of radius 1 m, north to (8, 5.5)."""
    leg = np.stack([np.linspace(5.0, 7.0, 21), np.full(21, 3.0)], axis=1)
    phi = np.linspace(0, np.pi / 2, 17)[1:]
    arc = np.stack([7.0 + np.sin(phi), 4.0 - np.cos(phi)], axis=1)
    tail = np.stack([np.full(15, 8.0), np.linspace(4.1, 5.5, 15)], axis=1)
    return np.concatenate([leg, arc, tail])


def write_bag(path: Path, storage: str, *, with_costmap: bool = True, pose_array: bool = False) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Pose, Point, Quat = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]

    def header(ns: int) -> object:
        return Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="map")

    def pose(x: float, y: float) -> object:
        return Pose(position=Point(x=x, y=y, z=0.0), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0))

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    traj, values = trajectory(), world()
    goal = traj[-1]
    sketch = np.array([[5.0, 3.0], [7.0, 3.0], [7.7, 3.3], [8.0, 4.0], goal])
    t0 = 1_000_000_000
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {}
        if with_costmap:
            conns["cm"] = writer.add_connection("/local_costmap/costmap", "nav_msgs/msg/OccupancyGrid", typestore=ts)
        conns["pose"] = writer.add_connection("/amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped", typestore=ts)
        wp_type = "geometry_msgs/msg/PoseArray" if pose_array else "nav_msgs/msg/Path"
        conns["wp"] = writer.add_connection("/waypoints", wp_type, typestore=ts)
        if pose_array:
            wp_msg = T[wp_type](header=header(t0), poses=[pose(*p) for p in sketch])
        else:
            stamped = T["geometry_msgs/msg/PoseStamped"]
            wp_msg = T[wp_type](header=header(t0), poses=[stamped(header=header(t0), pose=pose(*p)) for p in sketch])
        writer.write(conns["wp"], t0, ts.serialize_cdr(wp_msg, wp_type))
        for i, (x, y) in enumerate(traj):
            t = t0 + 10_000_000 + i * 100_000_000
            if with_costmap and i % 5 == 0:  # rolling window centred on the robot, snapped to the grid
                c0 = int(round(x / RES)) - SIZE // 2
                r0 = int(round(y / RES)) - SIZE // 2
                win = np.full((SIZE, SIZE), -1, np.int8)
                rs, cs = slice(max(r0, 0), min(r0 + SIZE, 100)), slice(max(c0, 0), min(c0 + SIZE, 120))
                win[rs.start - r0:rs.stop - r0, cs.start - c0:cs.stop - c0] = values[rs, cs]
                info = T["nav_msgs/msg/MapMetaData"](map_load_time=Time(sec=0, nanosec=0), resolution=RES, width=SIZE,
                                                     height=SIZE, origin=pose(c0 * RES, r0 * RES))
                msg = T["nav_msgs/msg/OccupancyGrid"](header=header(t - 1000), info=info, data=win.reshape(-1))
                writer.write(conns["cm"], t - 1000, ts.serialize_cdr(msg, "nav_msgs/msg/OccupancyGrid"))
            cov = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(x, y), covariance=np.zeros(36))
            msg = T["geometry_msgs/msg/PoseWithCovarianceStamped"](header=header(t), pose=cov)
            writer.write(conns["pose"], t, ts.serialize_cdr(msg, "geometry_msgs/msg/PoseWithCovarianceStamped"))


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_rosbag_round_trip(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / f"run_{storage}"
    write_bag(bag, storage, pose_array=storage == "mcap")
    cfg = small_cfg(tmp_path / "ds", shape="L", **{"rosbag.paths": [str(bag)]})
    summary = annotate(cfg)
    n_poses = len(trajectory())
    assert summary["instances"] == n_poses and summary["rejections"] == {}  # one instance per pose sample
    manifest = check_dataset(tmp_path / "ds", {"L"}, 30.0)
    assert manifest["labels"]["scenario_id"]["values"] == [f"run_{storage}/L000"]
    from spade.data.path_dataset import PathDataset

    item = PathDataset(tmp_path / "ds")[0]
    wp = item["waypoints"].numpy()
    # Robot frame: the robot at its fixed pixel (32, 48), the path leaving it straight up the window.
    np.testing.assert_allclose(wp[0], [SIZE / 2, 0.75 * SIZE], atol=1e-4)
    assert wp[3, 1] < wp[0, 1] and abs(wp[3, 0] - wp[0, 0]) < 1.0
    pose = item["pose"].numpy()
    np.testing.assert_allclose(pose[:2], trajectory()[0][:2], atol=0.05)  # recorded in map metres
    occ = np.rint(item["state"].numpy()[0] * 2)
    assert (occ == 2).any() and (occ == 0).any()  # the wall and the unknown outside the site


def test_rosbag_path_beyond_the_local_window_is_counted(tmp_path: Path) -> None:
    bag = tmp_path / "run"
    write_bag(bag, "sqlite3")
    cfg = small_cfg(tmp_path / "ds", shape="L", **{"rosbag.paths": [str(bag)]})
    cfg["window"]["size_px"] = 40  # 4 m: the goal is out of sight from the first poses
    summary = annotate(cfg)
    out = summary["rejections"]["path_outside_window"]
    assert out > 0 and summary["instances"] + out == len(trajectory())


def test_rosbag_without_a_required_topic(tmp_path: Path) -> None:
    bag = tmp_path / "nocostmap"
    write_bag(bag, "sqlite3", with_costmap=False)
    with pytest.raises(RosbagImportError, match=r"no topic '/local_costmap/costmap' \(rosbag.costmap_topic\); its "
                                                r"topics: /amcl_pose .*, /waypoints"):
        annotate(small_cfg(tmp_path / "ds", shape="L", **{"rosbag.paths": [str(bag)]}))


def skipp_fixture(root: Path, n: int = 4) -> Path:
    """A SKIPP task folder with one sequence of ``n`` states, in exactly the published layout."""
    seq = root / "U_Shape" / "0"
    seq.mkdir(parents=True)
    poses = []
    for i in range(1, n + 1):
        egm = np.full((256, 256), 75, np.uint8)  # grey: free
        egm[:20, :] = 0  # black: unseen
        egm[200:210, 20:230] = 255  # white: obstacle
        path = np.zeros((256, 256), np.uint8)
        start_col = 60 + 10 * i
        path[100, start_col:180] = 255  # out along row 100 ...
        t = np.linspace(-np.pi / 2, np.pi / 2, 200)
        rr, cc = np.rint(130 + 30 * np.sin(t)).astype(int), np.rint(180 + 30 * np.cos(t)).astype(int)
        path[rr, cc] = 255  # ... a U turn of radius 30 px ...
        path[160, 80:181] = 255  # ... and back along row 160 to the goal at (row 160, col 80)
        for r in (99, 101):
            path[r, start_col:180] = np.where(np.arange(start_col, 180) % 2, 255, 0)  # a 2-3 px wide stroke
        Image.fromarray(egm).save(seq / f"{i}_egm.jpg", quality=90)
        Image.fromarray(path).save(seq / f"{i}_path.png")
        poses.append([160, 80])
    np.save(seq / "egm_goal_poses.npy", np.array(poses))
    return root / "U_Shape"


def test_skipp_layout_import(tmp_path: Path) -> None:
    root = skipp_fixture(tmp_path / "skipp")
    cfg = small_cfg(tmp_path / "ds", shape="U", **{"skipp.root": str(root)})
    cfg["window"]["size_px"] = 128
    summary = annotate(cfg)
    assert summary["instances"] == 4
    manifest = check_dataset(tmp_path / "ds", {"U"}, 30.0)
    assert manifest["resolution"] == pytest.approx(0.02) and manifest["image_size"] == [128, 128]
    from spade.data.path_dataset import PathDataset

    item = PathDataset(tmp_path / "ds")[0]
    wp = item["waypoints"].numpy()
    # Robot frame: the far end of the stroke (the start, heading east along row 100) at the robot pixel
    # (64, 96), heading up; the goal (halved SKIPP pixels, 5 px east and 30 px south of the start) lands 30 px
    # to the right and 5 px up: a quarter turn clockwise of the image, no mirror.
    np.testing.assert_allclose(wp[0], [64, 96], atol=1e-4)
    np.testing.assert_allclose(wp[-1], [64 + 30, 96 - 5], atol=1.2)
    occ = np.rint(item["state"].numpy()[0] * 2)
    assert (occ == 2).any() and (occ == 0).any() and (occ == 1).any()


def test_skipp_missing_goal_poses(tmp_path: Path) -> None:
    root = skipp_fixture(tmp_path / "skipp")
    np.save(root / "0" / "egm_goal_poses.npy", np.zeros((2, 2)))
    with pytest.raises(SkippImportError, match=r"shape \(2, 2\), expected \(4, >=2\)"):
        annotate(small_cfg(tmp_path / "ds", shape="U", **{"skipp.root": str(root)}) | {"window": {
            **small_cfg(tmp_path / "ds")["window"], "size_px": 128}})
