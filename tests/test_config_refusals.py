"""Every option typed and ranged before any work: strict booleans, positive sizes, known metrics, window sizes
that agree, prerequisites checked wherever they come from, ``spade.critic``, ``spade.evaluate``'s ``drive.*`` and
``spade.closed_loop`` checked first; each refusal is one ``error: ...; <fix>`` line, exit status 2, with no run or
folder left behind."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from spade.config.preflight import validate_train_config
from spade.utils.errors import ConfigError

from factories import checkpoint, site_map, student_checkpoint, write_synthetic
from refusal_support import UNREACHABLE, assert_critic_refuses, one_error_line, store_runs
from training_helpers import compose_row

REPO = Path(__file__).resolve().parents[1]
ROW = "t1_small_bc_L"
FID = "metrics.fid_extractor=randconv"  # the offline extractor whose weights are generated, not shipped


def test_image_size_window_and_unet_downsampling_must_agree(spade_home: Path, tmp_path: Path) -> None:
    """``scale.image_size=62`` alone was ignored (data stayed 64 px); with the window at 62 px too the run
    generated data and trained and registered an expert before failing on "not divisible by 4". The window now
    follows ``scale.image_size`` (one stored size); a window set apart from it is still refused."""
    with pytest.raises(ConfigError, match=r"scale.image_size=64 differs from scale.annotate.window.size_px=60"):
        validate_train_config(compose_row(ROW, spade_home, "scale.annotate.window.size_px=60"))
    with pytest.raises(ConfigError, match=r"window.size_px=62 is not a multiple of 4.*model.size=small"):
        validate_train_config(compose_row(ROW, spade_home, "scale.image_size=62"))
    with pytest.raises(ConfigError, match=r"window.size_px=62 is not a multiple of 4.*model.size=small"):
        validate_train_config(compose_row(ROW, spade_home, "scale.image_size=62", "scale.annotate.window.size_px=62"))
    with pytest.raises(ConfigError, match="not a multiple of 4"):  # the row that trains an expert first, too
        validate_train_config(compose_row("t1_small_conddbc_L", spade_home, "scale.image_size=62",
                                          "scale.annotate.window.size_px=62"))
    # agreeing sizes pass (in a data folder of their own: the shared 64 px tiny datasets would be refused as other
    # settings, which is right)
    validate_train_config(compose_row(ROW, spade_home, "scale.image_size=72", "scale.annotate.window.size_px=72",
                                      f"paths.data_dir={tmp_path}"))


def test_an_expert_fetched_from_the_registry_is_checked_like_an_explicit_path(spade_home: Path, tmp_path: Path,
                                                                             monkeypatch) -> None:
    """A prerequisite from the Model Registry skipped the role, kind and geometry checks (they ran before
    the registry filled the path in)."""
    from spade.experiments import prerequisites
    from spade.tracking.registry import RegisteredCheckpoint
    from spade.experiments.run import train

    wrong_role = student_checkpoint(tmp_path / "cache" / "student.ckpt")
    wrong_size = student_checkpoint(tmp_path / "cache" / "expert32.ckpt", role="expert", size=32)
    for fetched, message in ((wrong_role, "is a student checkpoint, this key takes an expert"),
                             (wrong_size, "32 x 32 px")):
        monkeypatch.setattr(prerequisites, "fetch_registered",
                            lambda *a, _p=fetched, **k: RegisteredCheckpoint("expert", 1, "run", _p))
        cfg = compose_row("t1_small_conddbc_L", spade_home, "logger=none", f"paths.output_dir={tmp_path / 'out'}", FID)
        with pytest.raises(ConfigError, match=message) as info:
            train(cfg)
        assert "model.margin.expert_ckpt" in str(info.value)
    assert not (tmp_path / "out" / "checkpoints").exists()  # refused before anything was built


def test_a_registry_expert_of_the_wrong_kind_is_refused_before_training(spade_home: Path, tmp_path: Path,
                                                                       monkeypatch) -> None:
    """An expert fetched from the Model Registry passes the kind check of one given by path. A Cond-DBC
    row whose registry lookup returns an unconditional expert (right role, right window geometry) stops with the
    kind error, naming the key and the fix, before any data module, model or run is built; the same expert by path
    stops the same way."""
    import torch

    from spade.maps.frame import RobotFrame
    from spade.experiments import prerequisites
    from spade.experiments import run as run_module
    from spade.tracking.registry import RegisteredCheckpoint
    from spade.models.builders import build_model

    net = build_model("uncond_expert", "tiny")
    uncond = tmp_path / "cache" / "uncond.ckpt"
    uncond.parent.mkdir(parents=True)
    torch.save({"spade": {"role": "expert", "config": dict(net.config), "data": {
        "image_size": [64, 64], "resolution_m": 0.1, "frame": RobotFrame.for_size(64).to_json()}}}, uncond)
    fetched = []
    monkeypatch.setattr(prerequisites, "fetch_registered",
                        lambda *a, **k: fetched.append(a) or RegisteredCheckpoint("expert", 1, "run", uncond))
    row = ("t1_small_conddbc_L", spade_home, "logger=none", f"paths.output_dir={tmp_path / 'out'}", FID)
    cfg = compose_row(*row)
    built = []
    monkeypatch.setattr(run_module.hydra.utils, "instantiate", lambda *a, **k: built.append(a))
    with pytest.raises(ConfigError, match=r"model.margin.expert_ckpt=.*uncond.ckpt is an unconditional expert, but "
                                          r"Cond-DBC \(margin=cond_dbc\) needs a conditional one; pass a conditional "
                                          r"expert \(a cond_expert_\* experiment\)"):
        run_module.train(cfg)
    assert fetched and not built  # the registry filled the path in; nothing was instantiated after the refusal
    with pytest.raises(ConfigError, match="is an unconditional expert, but Cond-DBC"):
        validate_train_config(compose_row(*row, f"model.margin.expert_ckpt={uncond}"))


@pytest.mark.parametrize("override, key", [("registry.promote=maybe", "registry.promote='maybe' is not a boolean"),
                                           ("registry.promote=1", "registry.promote=1 is not a boolean"),
                                           ("optimized_metric=val/nonexistent",
                                            "optimized_metric=val/nonexistent is not a metric the student logs")])
def test_train_refuses_untyped_values_before_any_work(tmp_path: Path, run_main, override: str, key: str) -> None:
    """``registry.promote=maybe`` was accepted and registered a champion; ``optimized_metric=val/...``
    misspelt failed after the first epoch. Both are one line before any data is made or any run opened."""
    code, err = run_main("spade.train", ["+experiment=t1_small_bc_L", override])
    assert code == 2, err
    line = one_error_line(err)
    assert key in line
    home = tmp_path / "home"
    assert not (home / "data").exists() and store_runs(home / "logs" / "mlflow.db") == 0


def test_the_optimized_metric_is_one_the_role_logs() -> None:
    from spade.config.preflight import fit_metrics, train_options
    from spade.utils.config import compose_config

    student = fit_metrics(train_options(compose_config("train", ["+experiment=t1_small_conddbc_L"])))
    expert = fit_metrics(train_options(compose_config("train", ["+experiment=cond_expert_L"])))
    assert {"val/score_cm", "val/ape_cm", "val/loss_bc", "train/loss_dm", "margin/active"} <= student
    assert "val/loss" in expert and "val/loss_bc" not in expert and "test/ape_cm" not in student


def test_report_booleans_are_strict_and_it_reads_by_default(run_main, tmp_path: Path) -> None:
    """``log_to_runs=maybe`` was accepted (and wrote into every row's run); by default a report wrote its
    chart into the training runs although the guarantees page says readers only read. Now a report writes only
    into ``output_dir`` unless ``log_to_runs=true``."""
    from spade.utils.config import compose_config

    assert compose_config("report", []).log_to_runs is False
    for override in ("log_to_runs=maybe", "chart=1", "paper=yes"):
        code, err = run_main("spade.report", ["table=table1", override])
        assert code == 2, err
        key = override.split("=")[0]
        assert f"{key}=" in one_error_line(err) and "is not a boolean" in err
    assert "log_to_runs=true" in (REPO / "docs" / "reference" / "reliability.md").read_text()


def test_guarantees_page_says_what_report_writes() -> None:
    text = (REPO / "docs" / "reference" / "reliability.md").read_text()
    assert "log_to_runs=true" in text and "data=own" in text
    assert json.dumps  # the module's imports stay used


def test_export_checks_latency_batches_and_register_before_writing(tmp_path: Path, run_main) -> None:
    """``latency_batches=[0]`` printed latencies for a batch of 0; bad ``register=`` values failed after
    the export was written (one leaving a registered version without its alias). Each is refused first."""
    ckpt = student_checkpoint(tmp_path / "student.ckpt")
    cases = {"latency_batches=[0]": "latency_batches=[0] holds 0",
             "register=a/b": "register='a/b' is not a registered model name",
             "alias=latest": "alias='latest' is not a model alias",
             "format=torchscript": "only ONNX exports are registered",
             "paths.mlflow_tracking_uri=" + UNREACHABLE: "no tracking server answers there"}
    for override, expected in cases.items():
        extra = [] if override.startswith("latency") else ["register=spade-student"]
        code, err = run_main("spade.export", [f"ckpt_path={ckpt}", "latency_runs=0", *extra, override])
        assert code == 2, err
        assert expected in one_error_line(err), err
        assert not (tmp_path / "student.onnx").exists() and not (tmp_path / "student.pt").exists()


def test_bench_sizes_are_positive(run_main, tmp_path: Path) -> None:
    out = tmp_path / "b.json"
    for override in ("student.batches=[0]", "student.batches=3", "metrics.instances=0"):
        code, err = run_main("spade.bench", ["quick=true", f"out_json={out}", override])
        assert code == 2 and override.split("=")[0] in one_error_line(err), err
    assert not out.exists()


def test_annotation_settings_are_ranged_wherever_a_dataset_is_made(tmp_path: Path, run_main) -> None:
    """``robot.radius_m=-1`` and ``robot.inflation_radius_m=-3`` were written into datasets. Refused by
    spade.annotate, by a run that generates its data and by the sketch server, before any map is loaded."""
    from spade.config.sketch_checks import validate_sketch_config
    from spade.config.annotate_checks import check_annotation_settings
    from spade.utils.config import compose_config
    from spade.utils.errors import ConfigError

    out = tmp_path / "ds"
    for override, expected in (("robot.radius_m=-1", "robot.radius_m=-1 is out of range"),
                               ("robot.inflation_radius_m=-3", "robot.inflation_radius_m=-3 is out of range"),
                               ("instances.spacing_m=0", "instances.spacing_m=0 is out of range"),
                               ("template.p_mirror=2", "template.p_mirror=2 is out of range")):
        code, err = run_main("spade.annotate", [f"out_dir={out}", "num_instances=2", "maps=[warehouse:1]",
                                                "progress=false", override])
        assert code == 2, err
        assert expected in one_error_line(err)
        assert not out.exists()
    with pytest.raises(ConfigError, match=r"data\.train_generate: robot\.radius_m=-1 is out of range"):
        check_annotation_settings({"robot": {"radius_m": -1}}, "data.train_generate: ")
    yaml_path = site_map(tmp_path)
    cfg = compose_config("sketch", [f"map={yaml_path}", f"out_dir={tmp_path / 'sk'}", "++annotate.robot.radius_m=-1"])
    with pytest.raises(ConfigError, match=r"annotate\.robot\.radius_m=-1 is out of range"):
        validate_sketch_config(cfg)


def test_critic_checks_every_input_in_one_line(tmp_path: Path, run_main) -> None:
    """``spade.critic`` had no config check: a garbage store failed after a minute of measuring, and
    every bad input was a traceback. Each is now one line, before the expert is loaded."""
    test = tmp_path / "test"
    write_synthetic(test, n=4)
    expert = checkpoint(tmp_path / "expert.ckpt", "expert")
    student = checkpoint(tmp_path / "student.ckpt")
    garbage = tmp_path / "garbage.db"
    garbage.write_bytes(b"not a database at all" * 100)
    base = [f"ckpt_path={expert}", f"data.test_dir={test}", "data.test_shape=null", f"output_dir={tmp_path / 'out'}"]
    cases = {
        (f"ckpt_path={student}",): "is a student checkpoint, this key takes an expert",
        (f"student_ckpt={expert}",): "student_ckpt=",
        ("critic.bands=0",): "critic.bands=0 is out of range",
        ("critic.draws_per_band=two",): "critic.draws_per_band='two' is not an integer",
        (f"data.test_dir={tmp_path / 'none'}",): "holds no dataset",
        ("data.test_shape=Z",): "data.test_shape='Z'",
        (f"logger.mlflow.tracking_uri=sqlite:///{garbage}",): "is not an SQLite database",
        (f"logger.mlflow.tracking_uri={UNREACHABLE}",): "no tracking server answers there",
        ("model.margin.lambda_dm=-1",): "model.margin.lambda_dm",
        (f"output_dir={garbage}",): "is a file",
    }
    assert_critic_refuses(run_main, tmp_path, base, cases)


def expert_with_timesteps(path: Path, timesteps: int) -> Path:
    """An expert checkpoint (:func:`checkpoint`'s) whose hyper-parameters record ``timesteps`` training steps."""
    import torch

    checkpoint(path, "expert")
    data = torch.load(path, weights_only=False)
    data["hyper_parameters"] = {"num_train_timesteps": timesteps}
    torch.save(data, path)
    return path


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


def test_evaluate_refuses_source_seed_before_the_evaluation(tmp_path: Path, run_main) -> None:
    """``source_seed=abc`` failed after a whole evaluation, leaving a FINISHED run. Refused first, with
    no run in the store."""
    test = tmp_path / "test"
    write_synthetic(test, n=4)
    ckpt = checkpoint(tmp_path / "student.ckpt")
    for override, expected in (("source_seed=abc", "source_seed='abc' is not an integer"),
                               ("source_seed=-3", "source_seed=-3 is out of range"),
                               ("open_loop=maybe", "open_loop='maybe' is not a boolean"),
                               ("mcap_instances=0", "mcap_instances=0 is out of range")):
        code, err = run_main("spade.evaluate", [f"ckpt_path={ckpt}", "data=own", f"data.test_dir={test}", override])
        assert code == 2, err
        assert expected in one_error_line(err)
    assert store_runs(tmp_path / "home" / "logs" / "mlflow.db") == 0


@pytest.mark.parametrize("override, says", [
    ("drive.scenarios=0", "drive.scenarios=0 is out of range"),
    ("drive.baselines=shortest", "drive.baselines='shortest' is not a list of ['shortest', 'heading']"),
    ("drive.commit_tol_cm=-1", "drive.commit_tol_cm=-1 is out of range"),
    ("drive.mcap_episodes=-3", "drive.mcap_episodes=-3 is out of range"),
    ("drive.follower.speed_mps=0", "drive.follower.speed_mps=0 is out of range"),
    ("drive.noise_xy_m=abc", "drive.noise_xy_m='abc' is not a number"),
])
def test_drive_options_are_checked_before_the_evaluation(override: str, says: str) -> None:
    """``drive.*`` options were checked after the MLflow run opened (a FAILED run left) or not at all
    (``scenarios=0``, ``baselines=shortest`` read as the letter "s", a negative ``commit_tol_cm``,
    ``mcap_episodes=-3``). Now ``spade.evaluate``'s config check refuses each in one line, before the checkpoint is
    even read."""
    from spade.config.drive_checks import check_drive_config
    from spade.utils.config import compose_config
    from spade.utils.errors import ConfigError

    cfg = compose_config("evaluate", ["closed_loop=true", override])
    with pytest.raises(ConfigError) as info:
        check_drive_config(cfg)
    assert says in str(info.value) and "; " in str(info.value)
    check_drive_config(compose_config("evaluate", ["closed_loop=true"]))  # the defaults pass


def test_evaluate_with_nothing_to_evaluate_is_refused_in_one_line(tmp_path: Path, run_main) -> None:
    """``open_loop=false closed_loop=false`` was accepted; it is one line and exit 2 now, and no store is made."""
    ckpt = student_checkpoint(tmp_path / "s.ckpt")
    store = tmp_path / "mlflow.db"
    code, err = run_main("spade.evaluate", [f"ckpt_path={ckpt}", "open_loop=false", "closed_loop=false",
                                            f"paths.mlflow_tracking_uri=sqlite:///{store}"])
    assert code == 2 and "leaves nothing to evaluate" in one_error_line(err)
    assert not store.exists()
    code, err = run_main("spade.evaluate", [f"ckpt_path={ckpt}", "closed_loop=true", "drive.scenarios=0",
                                            f"paths.mlflow_tracking_uri=sqlite:///{store}"])
    assert code == 2 and "drive.scenarios=0 is out of range" in one_error_line(err) and not store.exists()


@pytest.mark.parametrize("override, says", [
    ("sources=[{table: guidance}]", "sources[0]="),
    ("sources=[{table: guidance, row: \"a'b\"}]", "sources[0].row=\"a'b\" is not a row name"),
    ("sources=guidance", "sources='guidance' is not a non-empty list"),
    ("datasets.heldout.scenarios=0", "datasets.heldout.scenarios=0 is out of range"),
    ("conditions.perturbed.noise_xy_m=-0.1", "conditions.perturbed.noise_xy_m=-0.1 is out of range"),
    ("+conditions.perturbed.nois_xy_m=0.1", "conditions.perturbed.nois_xy_m: no such drive setting"),
    ("+conditions.odd.baselines=shortest", "conditions.odd.baselines='shortest' is not a list"),
])
def test_closed_loop_is_checked_before_any_drive(tmp_path: Path, run_main, override: str, says: str) -> None:
    """``spade.closed_loop`` had no preflight: malformed ``sources``, a quote in a row name, a bad
    condition gave tracebacks or exit 0. Now one line and exit 2, before any store is opened."""
    store = tmp_path / "mlflow.db"
    code, err = run_main("spade.closed_loop", [override, f"tracking_uri=sqlite:///{store}"])
    assert code == 2, err
    assert says in one_error_line(err)
    assert not store.exists()


def test_closed_loop_refuses_sources_the_store_has_no_finished_run_of(tmp_path: Path, run_main) -> None:
    """An unknown table or row in a real store warned "no finished run ... launch it first" and exited 0 with "0 drives
    run". When no source can be driven it is one line naming the sources and the rows the store holds, exit 2."""
    from spade.deploy.mlflow_store import ensure_store, mlflow_client

    store = tmp_path / "mlflow.db"
    uri = f"sqlite:///{store}"
    ensure_store(uri)
    client = mlflow_client(uri)
    run = client.create_run(client.create_experiment("quickstart"), run_name="quickstart",
                            tags={"scale": "quickstart"})
    client.set_terminated(run.info.run_id, "FINISHED")
    code, err = run_main("spade.closed_loop", ["sources=[{table: nosuch, row: t1_small_bc_L}]", f"tracking_uri={uri}"])
    assert code == 2, err
    line = one_error_line(err)
    assert "nosuch/t1_small_bc_L" in line and "quickstart/quickstart" in line and "sources=[" in line, line
    code, err = run_main("spade.closed_loop", ["sources=[{table: quickstart, row: quickstart}]", "scale=tiny",
                                               f"tracking_uri={uri}"])  # trained, but at another scale
    assert code == 2 and "at scale tiny" in one_error_line(err), err
    from spade.config.drive_checks import check_source_rows

    check_source_rows(uri, [{"table": "nosuch", "row": "x"}, {"table": "quickstart", "row": "quickstart"}],
                      "quickstart")  # one source that can be driven: the launch drives it and warns of the other


def test_closed_loop_refuses_a_store_that_does_not_exist(tmp_path: Path, run_main) -> None:
    """A mistyped ``tracking_uri`` created an empty store, drove nothing and exited 0 ("0 drives run"). The drives
    read the source rows' finished runs from the store: a store that is not there is one line, and none is made."""
    typo = tmp_path / "mlfow.db"
    code, err = run_main("spade.closed_loop", [f"tracking_uri=sqlite:///{typo}"])
    assert code == 2, err
    line = one_error_line(err)
    assert f"there is no MLflow store at {typo}" in line and "tracking_uri" in line
    assert not typo.exists()


@pytest.mark.parametrize("override, says", [("rate_hz=0", "rate_hz=0"), ("speed_mps=-1", "speed_mps=-1"),
                                            ("goal_distance_m=[3.0,1.0]", "the minimum exceeds the maximum")])
def test_the_simulators_ranges_are_one_line_with_the_fix(run_main, override: str, says: str) -> None:
    """A bad range of ``spade.ros sim`` named the option without a fix; ``goal_distance_m=[3,1]`` started the
    simulator. Each is refused in one line that says where to set it."""
    code, err = run_main("spade.ros", ["sim", "map=warehouse:1", override])
    assert code == 2, err
    line = one_error_line(err)
    assert says in line and "conf/ros_sim.yaml" in line


@pytest.mark.parametrize("options, named", [({"precision": "banana"}, "trainer.precision='banana'"),
                                            ({"devices": -7}, "trainer.devices=-7"),
                                            ({"accelerator": "tpu"}, "trainer.accelerator=tpu")])
def test_a_trainer_option_lightning_refuses_is_one_line_naming_it(options: dict, named: str) -> None:
    """Lightning's own refusal of a trainer option (raised inside the constructor Hydra instantiates) reaches the
    user as one ``error:`` line with the fix, not Hydra's "Error in call to target" traceback."""
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate

    from spade.utils.errors import exit_on_errors

    with pytest.raises(InstantiationException) as raised:
        instantiate({"_target_": "spade.training.speed.build_trainer", "logger": False, **options})
    assert isinstance(raised.value.__cause__, ConfigError)

    def task() -> None:
        raise raised.value

    with pytest.raises(SystemExit) as ended:
        exit_on_errors((ConfigError,))(task)()
    assert ended.value.code == 2
    message = str(raised.value.__cause__)
    assert named in message and "\n" not in message and ("use one of" in message or "trainer.devices=1" in message)
