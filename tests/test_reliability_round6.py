"""Reliability, sixth round (issue 63, item 4): the unclear rows of the probe, one line each instead of a
traceback, and the slow ones bounded (a refusal names the limit).

- ``spade.critic``: ``model.margin.t_max`` beyond the expert's training timesteps refused before any work, naming
  the expert's T; ``critic.bands`` (and its draws) bounded;
- ``warehouse:abc`` (a procedural spec whose seed is not an integer) wherever a map spec is taken: one line, with
  the fix;
- ``models:/NAME/99``: one line naming the versions and aliases NAME has (or the names registered);
- a log folder that cannot be written (``hydra.run.dir``, ``paths.log_dir``, ``paths.output_dir``): one line naming
  it and the fix, before Hydra makes it;
- a sketch save keeps ``sketches.yaml``'s mode;
- an unsigned model at the sketch app's start-up: one line, unless ``allow_unsigned=true``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from factories import write_synthetic
from test_reliability_outputs import one_error_line, run_main  # noqa: F401 - a fixture
from test_reliability_round3 import real_export  # noqa: F401 - a fixture
from test_reliability_round4 import assert_critic_refuses, checkpoint

REPO = Path(__file__).resolve().parents[1]


def expert_with_timesteps(path: Path, timesteps: int) -> Path:
    """An expert checkpoint (:func:`checkpoint`'s) whose hyper-parameters record ``timesteps`` training steps."""
    import torch

    checkpoint(path, "expert")
    data = torch.load(path, weights_only=False)
    data["hyper_parameters"] = {"num_train_timesteps": timesteps}
    torch.save(data, path)
    return path


# -- 1, 2. spade.critic: the expert's timesteps, and bounded bands -----------------------------------------------------
def test_critic_refuses_t_max_beyond_the_expert_and_bounds_its_bands(tmp_path: Path, run_main) -> None:
    """``model.margin.t_max`` beyond the expert's T failed with a traceback once the expert was loaded;
    ``critic.bands=100000`` ran for minutes. Both are refused before the expert is loaded, naming the limit."""
    test = tmp_path / "test"
    write_synthetic(test, n=4)
    expert = expert_with_timesteps(tmp_path / "expert.ckpt", 50)
    base = [f"ckpt_path={expert}", f"data.test_dir={test}", "data.test_shape=null", f"output_dir={tmp_path / 'out'}"]
    cases = {
        ("model.margin.t_max=80",): "model.margin.t_max=80 exceeds the 50 training timesteps of the expert",
        ("critic.bands=100000",): "critic.bands=100000 exceeds the 50 timesteps",
        ("model.margin.t_min=10", "model.margin.t_max=20", "critic.bands=11"): "set critic.bands <= 10",
        ("critic.bands=40", "critic.draws_per_band=10"): "exceed the limit of 200",
    }
    assert_critic_refuses(run_main, tmp_path, base, cases)
    from spade.config.checkpoint_checks import expert_timesteps

    assert expert_timesteps(expert) == 50
    assert expert_timesteps(checkpoint(tmp_path / "plain.ckpt", "expert")) == 1000  # none recorded: the default


# -- 3. a procedural map spec with a non-integer seed ---------------------------------------------------------------
@pytest.mark.parametrize("module, args", [
    ("spade.plan", ["map=warehouse:abc", "start=[0.0,1.0,0.0]", "goal=[2.0,1.0]"]),
    ("spade.plan", ["warehouse:abc", "start=0,1,0", "goal=2,1"]),  # the map as the leading positional
    ("spade.annotate", ["maps=[warehouse:abc]", "num_instances=5", "out_dir={tmp}/ds"]),
    ("spade.annotate", ["maps=warehouse:abc", "num_instances=5", "out_dir={tmp}/ds"]),
    ("spade.sketch", ["map=warehouse:abc"]),
])
def test_a_procedural_spec_with_a_non_integer_seed_is_one_line(tmp_path: Path, run_main, module: str,
                                                               args: list[str]) -> None:
    """``warehouse:abc`` wherever a map spec is accepted: one line naming the spec and an integer seed."""
    code, err = run_main(module, [a.format(tmp=tmp_path) for a in args])
    assert code == 2, err
    line = one_error_line(err)
    assert "warehouse:abc" in line and "is not an integer" in line and "warehouse:3" in line, line
    assert not (tmp_path / "ds").exists()


# -- 4. a registry version that does not exist ---------------------------------------------------------------------
def test_a_missing_registry_version_names_the_versions_that_exist(tmp_path: Path, run_main) -> None:
    """``model=models:/NAME/99`` answered MLflow's error for an unknown version; now one line naming the versions
    (and aliases) NAME has, and an unknown name is answered with the names that are registered."""
    from factories import site_map
    from spade.deploy.mlflow_store import ensure_store, mlflow_client

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    ensure_store(uri)
    client = mlflow_client(uri)
    client.create_registered_model("stu")
    for _ in range(2):
        client.create_model_version("stu", source=str(tmp_path / "nowhere"))
    client.set_registered_model_alias("stu", "champion", "2")
    yaml_path = site_map(tmp_path)
    query = [f"map={yaml_path}", "start=[0.0,1.0,0.0]", "goal=[2.0,1.0]", f"paths.mlflow_tracking_uri={uri}",
             f"out={tmp_path / 'plan.png'}"]
    code, err = run_main("spade.plan", [*query, "model_path=models:/stu/99"])
    assert code == 2, err
    line = one_error_line(err)
    assert "models:/stu/99" in line and "stu has versions [1, 2]" in line and "champion" in line, line
    code, err = run_main("spade.plan", [*query, "model_path=models:/stu@best"])
    assert code == 2 and "stu has versions [1, 2]" in one_error_line(err), err
    code, err = run_main("spade.plan", [*query, "model_path=models:/other/1"])
    assert code == 2, err
    line = one_error_line(err)
    assert "no model is registered as 'other'" in line and "['stu']" in line, line
    assert not (tmp_path / "plan.png").exists()


# -- 5. read-only log folders --------------------------------------------------------------------------------------
def test_a_log_folder_that_cannot_be_written_is_one_line(tmp_path: Path, run_main) -> None:
    """A run folder Hydra cannot make (a read-only ``hydra.run.dir``, ``SPADE_HOME`` or ``paths.log_dir``) was
    Hydra's ``PermissionError`` traceback; ``paths.output_dir`` given a folder of its own likewise. Each is now one
    line naming the folder and the fix, before the command's work. /proc takes no files, whoever runs the test."""
    query = ["map=warehouse:1", "start=[1.0,1.0,0.0]", "goal=[2.0,1.0]", f"out={tmp_path / 'plan.png'}"]
    cases = [
        ("spade.plan", [*query, "hydra.run.dir=/proc/spade_run"], "hydra.run.dir=/proc/spade_run: the folder /proc"),
        ("spade.plan", [*query, "paths.log_dir=/proc/spade_logs"], "hydra.run.dir=/proc/spade_logs/runs/plan/"),
        ("spade.plan", [*query, "paths.output_dir=/proc/spade_out", f"hydra.run.dir={tmp_path / 'run'}"],
         "paths.output_dir=/proc/spade_out: the folder /proc"),
        ("spade.annotate", ["maps=[warehouse:1]", "num_instances=2", f"out_dir={tmp_path / 'ds'}",
                            "hydra.run.dir=/proc/spade_run"], "hydra.run.dir=/proc/spade_run: the folder /proc"),
    ]
    for module, args, expected in cases:
        code, err = run_main(module, args, hydra=False)
        assert code == 2, (args, err)
        line = one_error_line(err)
        assert expected in line and "paths.log_dir=DIR" in line, (args, line)
    assert not (tmp_path / "plan.png").exists() and not (tmp_path / "ds").exists()
    assert not (tmp_path / "run").exists()


# -- 6. a sketch save keeps the file's mode ------------------------------------------------------------------------
def test_a_sketch_save_keeps_the_files_mode(tmp_path: Path) -> None:
    """Every save rewrote ``sketches.yaml`` through ``mkstemp``, leaving it at mode 0600 whatever it was; a save now
    keeps the file's own mode, and a new file gets the umask's."""
    import os
    import stat

    from spade.sketching.storage import SketchStore

    waypoints = [[1.0, 1.0], [1.5, 1.0], [2.0, 1.5]]
    path = tmp_path / "sk" / "sketches.yaml"
    old = os.umask(0o022)
    try:
        store = SketchStore(path, "warehouse:1")
        store.append("L", waypoints)
        assert stat.S_IMODE(path.stat().st_mode) == 0o644
        path.chmod(0o664)
        store.append("L", waypoints)
        assert stat.S_IMODE(path.stat().st_mode) == 0o664
        path.chmod(0o640)
        SketchStore(path, "warehouse:1").append("L", waypoints)
        assert stat.S_IMODE(path.stat().st_mode) == 0o640
    finally:
        os.umask(old)


# -- 7. a forged model at the sketch app's start-up ----------------------------------------------------------------
def test_the_sketch_app_refuses_an_unsigned_model_unless_allowed(real_export: Path, tmp_path: Path,
                                                                 run_main) -> None:
    """A model export without an integrity record given to ``spade.sketch`` at start-up: refused in one line naming
    the sketch app's own opt-in (``allow_unsigned=true``); with it, the app opens the model, warned."""
    from test_reliability_round3 import _metadata
    from test_reliability_round5 import occupancy_graph

    from factories import site_map
    from spade.models.onnx_check import UncheckedExportWarning
    from spade.sketching import build_app

    meta = {k: v for k, v in _metadata(real_export).items() if k != "integrity"}
    forged = occupancy_graph(tmp_path / "forged.onnx", meta)
    yaml_path = site_map(tmp_path)
    base = [f"map={yaml_path}", f"out_dir={tmp_path / 'sk'}", f"model_path={forged}"]
    code, err = run_main("spade.sketch", base)
    assert code == 2, err
    line = one_error_line(err)
    assert "carries no integrity record" in line and "spade.sketch: allow_unsigned=true" in line, line
    code, err = run_main("spade.sketch", [*base, "allow_unsigned=maybe"])
    assert code == 2 and "allow_unsigned='maybe' is not a boolean" in one_error_line(err), err
    with pytest.warns(UncheckedExportWarning, match="opened unchecked"):
        build_app(str(yaml_path), tmp_path / "sk", model=forged, allow_unsigned=True)
