"""Alternative demonstrations: the vectorised template draws and pass tests against the scalar generator, the
sampler on a real scenario, and the dataset that stores them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy import stats

from spade.annotation.alternative_demonstrations import (
    AlternativesSettings,
    TemplateDraws,
    keypoint_polylines,
    keypoints_pass,
    sample_templates,
    scenario_alternatives,
)
from spade.annotation.pipeline import build_contexts
from spade.annotation.scenarios import plan_scenario, state_indices_along
from spade.annotation.sources import load_map_sources
from spade.annotation.templates import SHAPES, turn_curve, place_template, sample_template
from spade.data.path_dataset import PathDataset
from spade.maps.frame import RobotFrame, path_heading

from annotation_support import small_cfg

TEMPLATE = small_cfg(Path("unused"))["template"]


@pytest.mark.parametrize("shape", ["L", "U"])
def test_vectorised_draws_follow_the_generators_distribution(shape: str) -> None:
    rng = np.random.default_rng(0)
    scalar = [sample_template(shape, TEMPLATE, rng) for _ in range(3000)]
    vec = sample_templates(shape, TEMPLATE, np.random.default_rng(1), 3000)
    for name, a, b in (("leg", [t.leg_m for t in scalar], vec.leg), ("radius", [t.radius_m for t in scalar], vec.radius),
                       ("tail", [t.tail_m for t in scalar], vec.tail),
                       ("heading", [t.heading_rad for t in scalar], vec.theta)):
        assert stats.ks_2samp(a, b).pvalue > 1e-3, name
    assert abs(np.mean([t.mirror for t in scalar]) - np.mean(vec.sign < 0)) < 0.05


@pytest.mark.parametrize("shape", ["L", "U"])
def test_keypoint_polylines_are_the_generators_clicked_waypoints(shape: str) -> None:
    t = sample_templates(shape, TEMPLATE, np.random.default_rng(2), 40)
    kp, counts = keypoint_polylines(t, TEMPLATE, shape)
    for b in range(len(t)):
        ref, _ = turn_curve(t.leg[b], t.radius[b], t.tail[b], SHAPES[shape], t.sign[b] > 0, 0.05,
                             TEMPLATE[shape]["turn_keypoints"], TEMPLATE["keypoint_spacing_m"])
        assert counts[b] == len(ref)
        np.testing.assert_allclose(kp[b, :counts[b]], ref, atol=1e-9)


def _one(t: TemplateDraws, b: int) -> TemplateDraws:
    return TemplateDraws(t.leg[b:b + 1], t.radius[b:b + 1], t.tail[b:b + 1], t.sign[b:b + 1], t.theta[b:b + 1],
                         t.turn)


@pytest.mark.parametrize("shape", ["L", "U"])
def test_a_template_passes_its_own_waypoints_and_not_a_pose_beside_them(shape: str) -> None:
    """The vectorised prefilter against the template placed by the generator's own code (place_template)."""
    rng = np.random.default_rng(3)
    res, goal = 0.1, np.array([100.0, 80.0])
    for _ in range(10):
        st = sample_template(shape, TEMPLATE, rng)
        t = TemplateDraws(np.array([st.leg_m]), np.array([st.radius_m]), np.array([st.tail_m]),
                          np.array([-1.0 if st.mirror else 1.0]), np.array([st.heading_rad]), np.deg2rad(SHAPES[shape]))
        keypoints, _ = place_template(st, goal, res)
        chords = np.diff(keypoints, axis=0)
        chords = chords[np.linalg.norm(chords, axis=1) > 1e-6]
        starts = keypoints[:-1][np.linalg.norm(np.diff(keypoints, axis=0), axis=1) > 1e-6]
        headings = np.arctan2(chords[:, 1], chords[:, 0])
        middle = starts + chords / 2  # a pose at each chord's middle, heading along it
        on = np.column_stack([middle, headings])
        assert keypoints_pass(t, goal, on, res, 0.1, np.deg2rad(0.5), TEMPLATE, shape).all()
        normal = np.column_stack([-np.sin(headings), np.cos(headings)])
        beside = np.column_stack([middle + 2.0 * normal, headings])
        assert not keypoints_pass(t, goal, beside, res, 0.75, np.deg2rad(3), TEMPLATE, shape).any()
        # on the first leg chord, 5 degrees off: no chord of the template runs that way there
        turned = np.column_stack([middle[:1], headings[:1] + np.deg2rad(5)])
        assert not keypoints_pass(t, goal, turned, res, 0.75, np.deg2rad(3), TEMPLATE, shape).any()


@pytest.fixture(scope="module")
def scenario() -> tuple:
    cfg = small_cfg(Path("unused"))
    ctx = build_contexts(load_map_sources(["warehouse:1"], cfg["window"]["resolution_m"]), cfg)[0]
    result = plan_scenario(ctx, "L", 0, cfg)
    assert result.executed is not None
    states = state_indices_along(ctx, result.executed, cfg)[::4]
    return ctx, cfg, result, states


def test_alternatives_pass_the_robot_and_end_on_the_goal(scenario: tuple) -> None:
    ctx, cfg, result, states = scenario
    settings = AlternativesSettings(count=6, max_draws=40960)
    alts, counters = scenario_alternatives(ctx.costmap, "L", result.sketch[-1], result.executed.points, states, cfg,
                                           settings, np.random.default_rng(0))
    frame = RobotFrame.for_size(int(cfg["window"]["size_px"]))
    assert set(alts) == {int(i) for i in states}
    assert counters["accepted"] == sum(len(v) for v in alts.values()) > 0
    assert counters["draws"] <= settings.max_draws
    for i, rows in alts.items():
        assert rows.shape[1:] == (cfg["num_waypoints"], 2) and len(rows) <= settings.count
        pose = frame.place(result.executed.points[i], path_heading(result.executed.points, i))
        goal = pose.to_window(result.executed.points[-1:])[0]
        for row in rows:
            assert np.allclose(row[0], frame.robot_px, atol=1e-6)  # starts on the robot
            assert np.linalg.norm(row[-1] - goal) < 0.75  # ends where the demonstration ends (the goal's cell)
            assert np.linalg.norm(np.diff(row, axis=0), axis=1).max() < 3  # evenly resampled, connected
    # another draw of the same scenario is another sample; the same seed is the same one
    again, _ = scenario_alternatives(ctx.costmap, "L", result.sketch[-1], result.executed.points, states, cfg,
                                     settings, np.random.default_rng(0))
    assert all(np.array_equal(alts[i], again[i]) for i in alts)


def test_alternatives_differ_from_the_demonstration_where_the_state_allows(scenario: tuple) -> None:
    """Before the turn, an L from the same pose to the same goal can turn sharper or wider: the alternatives
    spread; on the tail every alternative drives the same straight line."""
    ctx, cfg, result, states = scenario
    first, last = int(states[0]), int(states[-1])
    settings = AlternativesSettings(count=8, max_draws=81920)
    alts, _ = scenario_alternatives(ctx.costmap, "L", result.sketch[-1], result.executed.points,
                                    np.array([first, last]), cfg, settings, np.random.default_rng(1))
    frame = RobotFrame.for_size(int(cfg["window"]["size_px"]))

    def spread(i: int) -> float:
        rows = alts[i]
        assert len(rows) >= 2
        return float(np.linalg.norm(rows - rows.mean(axis=0), axis=2).mean())

    pose = frame.place(result.executed.points[last], path_heading(result.executed.points, last))
    remaining = pose.to_window(result.executed.points[last:])
    if abs(np.ptp(remaining[:, 0])) < 1.0:  # the last state is on the straight tail
        assert spread(last) < spread(first)
    assert spread(first) > 0.2


def test_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="no key"):
        AlternativesSettings.from_cfg({"cuont": 3})
    with pytest.raises(ValueError, match="count"):
        AlternativesSettings.from_cfg({"count": 300})
    with pytest.raises(ValueError, match="shapes"):
        AlternativesSettings.from_cfg({"count": 3, "shapes": ["S"]})
    assert AlternativesSettings.from_cfg({"count": 3, "shapes": "L"}).wanted("L")
    assert not AlternativesSettings.from_cfg({"count": 3, "shapes": "L"}).wanted("U")


def test_a_test_set_stores_them_and_the_loader_gives_them(tmp_path: Path) -> None:
    from spade.annotate import annotate

    cfg = small_cfg(tmp_path / "alt", num_instances=24, shape=["L", "U"])
    cfg["alternatives"].update(count=3, max_draws=20480, shapes=["L"])
    annotate(cfg)
    manifest = json.loads((tmp_path / "alt" / "manifest.json").read_text())
    info = manifest["alternatives"]
    assert info["count"] == 3 and info["version"] == 1 and info["settings"]["shapes"] == ["L"]
    assert "alternatives" in manifest["files"] and manifest["extra"]["alternatives_sampler"]["accepted"] > 0
    ds = PathDataset(tmp_path / "alt")
    shapes = ds.labels("shape")
    have = []
    for i in range(len(ds)):
        rows = ds[i]["alternatives"]
        assert rows.shape == (3, cfg["num_waypoints"], 2)
        finite = torch.isfinite(rows).all(dim=(1, 2))
        assert not (~finite[:-1] & finite[1:]).any()  # NaN rows only after the drawn ones
        have.append(int(finite.sum()))
        if shapes[i] == "U":
            assert have[-1] == 0  # shapes=[L]
    assert max(have) > 0
    # the instances themselves are those of the same set drawn without alternatives
    plain = small_cfg(tmp_path / "plain", num_instances=24, shape=["L", "U"])
    annotate(plain)
    for name in ("occupancy", "start", "goal", "path", "waypoints", "pose"):
        assert (tmp_path / "alt" / f"{name}.bin").read_bytes() == (tmp_path / "plain" / f"{name}.bin").read_bytes()
    assert "alternatives" not in PathDataset(tmp_path / "plain")[0]


def test_corrupt_alternatives_are_refused(tmp_path: Path) -> None:
    from spade.annotate import annotate
    from spade.data.format import DatasetError

    cfg = small_cfg(tmp_path / "alt", num_instances=8, shape="L")
    cfg["alternatives"].update(count=2, max_draws=8192)
    annotate(cfg)
    path = tmp_path / "alt" / "alternatives.bin"
    data = bytearray(path.read_bytes())
    data[10] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match="alternatives"):
        PathDataset(tmp_path / "alt")


def test_the_floor_recomputed_from_the_files_alone_agrees(tmp_path: Path) -> None:
    """The metric's floor against a numpy re-implementation reading the dataset's files (spade.perf.alternatives),
    and a second estimator (the set's medoid) within 15 %; the worker count never changes the alternatives."""
    from spade.annotate import annotate
    from spade.perf.alternatives import independent_floor

    roots = []
    for workers in (1, 2):
        cfg = small_cfg(tmp_path / f"w{workers}", num_instances=16, shape="L", workers=workers)
        cfg["alternatives"].update(count=4, max_draws=12288)
        annotate(cfg)
        roots.append(tmp_path / f"w{workers}")
    assert (roots[0] / "alternatives.bin").read_bytes() == (roots[1] / "alternatives.bin").read_bytes()
    out = independent_floor(str(roots[0]), "L")
    assert out["instances"] > 0
    assert out["metric_floor_cm"] == pytest.approx(out["independent_median_floor_cm"], rel=1e-5)
    assert out["independent_medoid_floor_cm"] == pytest.approx(out["metric_floor_cm"], rel=0.15)


@pytest.mark.slow  # the sampler twice and its prefilter's capture, on a small set: about a minute
def test_the_sampler_check_writes_its_page(tmp_path: Path) -> None:
    from spade.annotate import annotate
    from spade.perf.alternatives import main

    cfg = small_cfg(tmp_path / "set", num_instances=12, shape="L")
    cfg["alternatives"].update(count=2, max_draws=8192)
    annotate(cfg)
    main([f"dataset={tmp_path / 'set'}", "scenarios=1", "states=2", "count=2", f"output_dir={tmp_path / 'out'}"])
    page = (tmp_path / "out" / "alternatives.md").read_text()
    assert "paired t-test" in page and "What the shipped prefilter loses" in page and "- commit:" in page
    assert "Provenance:\n\n- command: " in page  # a list after a blank line, as Markdown needs


def test_a_test_set_without_alternatives_loads_and_the_run_says_so(tmp_path: Path, caplog) -> None:
    import logging

    from spade.annotate import annotate
    from spade.data.datamodule import PathDataModule

    annotate(small_cfg(tmp_path / "train", num_instances=8, shape="L"))
    annotate(small_cfg(tmp_path / "old", num_instances=8, shape="L", seed=7, maps=["hall:5"]))  # count=0: as before
    dm = PathDataModule(tmp_path / "train", test_dir=tmp_path / "old", batch_size=4)
    with caplog.at_level(logging.WARNING, logger="spade.data.datamodule"):
        dm.setup("test")
    assert len(dm.test_set) == 8
    said = [r.getMessage() for r in caplog.records if "no alternative demonstrations" in r.getMessage()]
    assert len(said) == 1 and "floor_cm" in said[0] and "alternatives.count" in said[0]


def test_a_partly_nan_or_infinite_alternative_is_refused(tmp_path: Path) -> None:
    import hashlib

    from spade.annotate import annotate
    from spade.data.format import DatasetError

    cfg = small_cfg(tmp_path / "alt", num_instances=8, shape="L")
    cfg["alternatives"].update(count=2, max_draws=8192)
    annotate(cfg)
    root = tmp_path / "alt"
    manifest = json.loads((root / "manifest.json").read_text())
    path = root / "alternatives.bin"
    values = np.fromfile(path, dtype="<f4").reshape(8, 2, cfg["num_waypoints"], 2)
    i, j = np.argwhere(np.isfinite(values).all(axis=(2, 3)))[0]
    values[i, j, 5, 0] = np.inf
    values.tofile(path)
    manifest["files"]["alternatives"]["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    from spade.data.format import MANIFEST_CHECKSUM, manifest_checksum

    manifest[MANIFEST_CHECKSUM] = manifest_checksum(manifest)  # the arrays' own checks must refuse it
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match=f"instance {i} holds a row that is partly NaN, or holds inf"):
        PathDataset(root)
