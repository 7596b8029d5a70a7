"""``spade.train``'s preflight: everything in a run's config that needs no training, before any MLflow run opens.

The options of each configurable, built as their typed dataclasses, which check themselves
(:class:`~spade.config.options.TrainerBudget`, :class:`~spade.data.datamodule_options.DataOptions`, the model's
:class:`~spade.training.module_options.StudentOptions` or :class:`~spade.training.module_options.ExpertOptions`,
the margin's :class:`~spade.training.margin.MarginConfig`: the classes the modules themselves build); then what
crosses components: the run's own keys (seed, registry, the metric it optimises, which depends on the model's
role), the store it logs to, the data's folders and windows against the model, and every checkpoint the run
names (``ckpt_path``, ``model.init_ckpt``, ``model.margin.expert_ckpt``): its role, its geometry against the data,
the expert's kind against the margin, and the run a resume would continue.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from omegaconf import DictConfig

from spade.config.checkpoint_checks import check_checkpoint, check_geometry
from spade.config.dataset_checks import check_data, check_datasets
from spade.config.file_checks import check_paths
from spade.config.store_checks import check_logger_store, store_path
from spade.config.options import TrainerBudget, model_options_type, model_role, read_options
from spade.config.values import check_bool, check_choice, check_int, get
from spade.training.expert_mismatch import ExpertMismatchError
from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING, unset


def validate_train_config(cfg: DictConfig) -> None:
    """Every check of ``spade.train``'s config that needs no training: raises :class:`ConfigError` (one line)."""
    check_paths(cfg)  # first: an empty paths.data_dir would generate datasets under the filesystem root
    check_int(cfg, "seed", 0, 2**32 - 1, none_ok=True, fix=", e.g. seed=42")
    check_choice(cfg, "prerequisites", ["train", "error"])
    for key in ("train", "test", "test_untrained"):
        check_bool(cfg, key)
    check_logger_store(cfg)
    for key in ("closed_loop",):
        check_bool(cfg, key)
    _check_registry(cfg)
    read_options(cfg, TrainerBudget)
    check_data(cfg)
    _check_model(cfg)
    _check_optimized_metric(cfg)
    check_checkpoints(cfg)
    unlabelled = get(cfg, "data.unlabelled_dir")
    check_datasets(cfg, ("train", "test") if unlabelled in (MISSING, None, "") else ("train", "test", "unlabelled"))


def validate_checkpoints(cfg: DictConfig) -> None:
    """The role, kind and geometry checks of every checkpoint a run names (``ckpt_path``, ``model.init_ckpt``,
    ``model.margin.expert_ckpt``), again after the prerequisites filled paths from the Model Registry: a
    fetched model passes the same checks as one given by path."""
    check_checkpoints(cfg)


def _check_registry(cfg: DictConfig) -> None:
    """``registry.*``: a name prefix (a string, or null: nothing registered), ``promote`` a strict boolean (``maybe``
    would have promoted the new version to @champion), ``tags`` a mapping."""
    check_bool(cfg, "registry.promote")
    prefix = get(cfg, "registry.prefix")
    if prefix not in (MISSING, None) and (not isinstance(prefix, str) or not prefix.strip()):
        raise ConfigError(f"registry.prefix={prefix!r} is not a model name prefix; set registry.prefix=NAME (letters, "
                          "digits, '-', '_') or registry.prefix=null to register nothing")
    tags = get(cfg, "registry.tags")
    if tags not in (MISSING, None) and not isinstance(tags, Mapping):
        raise ConfigError(f"registry.tags={tags!r} is not a mapping; set registry.tags={{KEY: VALUE}} or leave it {{}}")


def fit_metrics(cfg: DictConfig) -> set[str] | None:
    """The metrics the configured module logs while it trains (what ``optimized_metric`` may name: it picks the
    best checkpoint, so a test metric would never be seen): ``val/`` + the validation figures
    (:class:`~spade.metrics.path_metrics.PathMetrics` without the planner, with its preference and FID keys), the
    role's losses, and a guided student's margin figures. None for a module this check does not know."""
    role = model_role(cfg)
    if role is None:
        return None
    import warnings

    from spade.metrics.path_metrics import PathMetrics
    from spade.metrics.preference import PREFERENCE_KEYS

    with warnings.catch_warnings():  # compute() before update(): the keys, not values, are wanted
        warnings.simplefilter("ignore")
        figures = set(PathMetrics(planner=False, fid=False).compute())
    figures |= {"floor_cm", *PREFERENCE_KEYS, "fid", "fid_real_count", "fid_fake_count"}
    names = {f"val/{k}" for k in figures}
    if role == "student":
        names |= {"val/loss_bc", "train/loss", "train/loss_bc"}
        if get(cfg, "model.margin") not in (MISSING, None, {}):
            names |= {"train/loss_dm", "train/margin_active", "margin/active", "margin/value"}
    else:
        names |= {"val/loss", "train/loss"}
    return names


def _check_optimized_metric(cfg: DictConfig) -> None:
    """``optimized_metric`` names a metric the module logs while training (:func:`fit_metrics`): a misspelt one
    failed only after the first validation (the checkpoint callback monitors it), an epoch of work lost."""
    metric = get(cfg, "optimized_metric")
    if metric in (MISSING, None):
        return
    if not isinstance(metric, str) or not metric.strip():
        raise ConfigError(f"optimized_metric={metric!r} must be a metric name such as val/score_cm; set "
                          "optimized_metric=val/score_cm (a student) or val/loss (an expert)")
    names = fit_metrics(cfg)
    if names is None or metric in names:
        return
    role = model_role(cfg)
    shown = sorted(n for n in names if n.startswith("val/"))
    raise ConfigError(f"optimized_metric={metric} is not a metric the {role} logs while training; set it to one of "
                      f"{', '.join(shown)} (or {', '.join(sorted(names - set(shown)))})")


def _check_model(cfg: DictConfig) -> None:
    """The model's options (those of its class: :func:`~spade.config.options.model_options_type`) and a student's
    margin options (:class:`~spade.training.margin.MarginConfig`'s checks)."""
    options = model_options_type(cfg)
    if options is None:
        return
    read_options(cfg, options)
    if options.role == "student":
        margin_config(cfg)  # model.margin's options, by MarginConfig's checks (lambda_dm >= 0, kind...)


def margin_config(cfg: DictConfig) -> Any:
    """``model.margin`` as a :class:`~spade.training.margin.MarginConfig` (None without a margin): its checks are
    MarginConfig's, reported as one line naming ``model.margin.<option>``."""
    from spade.training.margin import MarginConfig, MarginOptionError  # heavy: the margin imports Lightning

    options = get(cfg, "model.margin")
    if options in (MISSING, None):
        return None
    if not isinstance(options, Mapping):
        raise ConfigError(f"model.margin={options!r} is not a group of margin options; choose margin=none, "
                          "margin=dbc or margin=cond_dbc")
    try:
        return MarginConfig.from_options(options)
    except MarginOptionError as exc:
        raise ConfigError(exc.at("model.margin.")) from None


def check_checkpoints(cfg: DictConfig) -> None:
    role = model_role(cfg)
    train_data = ("train_dir", "test_dir")
    ckpt = get(cfg, "ckpt_path")
    if isinstance(ckpt, str) and not ckpt.strip():
        raise ConfigError("ckpt_path='' is empty; pass checkpoints/last.ckpt of an interrupted run to resume it, or "
                          "leave ckpt_path unset (ckpt_path=null) to start a new run")
    if ckpt is not MISSING and role is not None:
        fix = "pass checkpoints/last.ckpt of an interrupted run of this experiment (under its logs/runs/ folder)"
        info = check_checkpoint("ckpt_path", ckpt, role, fix)
        check_geometry("ckpt_path", ckpt, info, cfg, train_data)
        _check_resume(cfg, ckpt, info)
    init = get(cfg, "model.init_ckpt")
    if init is not MISSING:
        wanted = role or "student"  # a student starts from a student, an expert from an expert
        info = check_checkpoint("model.init_ckpt", init, wanted,
                                 f"pass a {wanted} checkpoint (the pretrained {wanted} the run fine-tunes)")
        check_geometry("model.init_ckpt", init, info, cfg, train_data)
    expert = get(cfg, "model.margin.expert_ckpt")
    if expert is not MISSING:
        info = check_checkpoint("model.margin.expert_ckpt", expert, "expert",
                                 "pass an expert checkpoint (from a cond_expert_* or uncond_expert_* experiment), or leave it null so that "
                                 "the experiment's requires.expert finds or trains one")
        check_geometry("model.margin.expert_ckpt", expert, info, cfg, train_data)
        check_expert_kind(cfg, expert, info)
    teacher = get(cfg, "data.unlabelled_teacher")
    if teacher not in (MISSING, None, ""):
        if get(cfg, "data.unlabelled_labels") is not True or get(cfg, "data.unlabelled_dir") in (MISSING, None, ""):
            raise ConfigError(f"data.unlabelled_teacher={teacher} labels the unlabelled states: set data.unlabelled_dir "
                              "and data.unlabelled_labels=true with it (or drop it)")
        info = check_checkpoint("data.unlabelled_teacher", teacher, "expert",
                                "pass a conditional expert checkpoint (a cond_expert_* or teacher_* run's best)")
        check_geometry("data.unlabelled_teacher", teacher, info, cfg, train_data)


# What a resumed run must share with the run its checkpoint was written under: (config key, MLflow parameter).
RESUME_KEYS = (("run_name", "cfg/run_name"), ("seed", "cfg/seed"), ("model.size", "cfg/model/size"),
               ("scale.name", "cfg/scale/name"))


def _check_resume(cfg: DictConfig, ckpt: Any, info: dict[str, Any] | None) -> None:
    """``ckpt_path`` resumes the MLflow run the checkpoint was written under. Refused before any work (so that no
    command changes a run it did not start): a run this store does not hold, a FINISHED run, and a checkpoint of
    another row, seed, size or scale (each named with both values)."""
    if get(cfg, "train") not in (True, MISSING) or not ckpt:
        return  # train=false: the checkpoint's weights are tested, nothing is resumed
    run_id = (info or {}).get("mlflow_run_id")
    uri = get(cfg, "logger.mlflow.tracking_uri")
    if not run_id or unset(uri):
        return  # written without MLflow, or MLflow off: nothing to continue
    uri = str(uri)
    new_run = ("start a new run instead (drop ckpt_path" + (", or start from its weights with model.init_ckpt="
                                                              f"{ckpt}" if model_role(cfg) == "student" else "") + ")")
    path = store_path(uri)
    if path is not None and not path.exists():
        raise ConfigError(f"ckpt_path={ckpt} was written under MLflow run {run_id}, but there is no store at {uri}; "
                          f"resume with the store it was logged to (SPADE_HOME or paths.mlflow_tracking_uri), or "
                          f"{new_run}")
    # heavy (MLflow), for a resume only; the store itself was checked by validate_train_config (check_logger_store)
    from spade.tracking.client import mlflow_client

    try:
        run = mlflow_client(uri).get_run(run_id)
    except Exception:  # noqa: BLE001 - not in this store (or unreachable): say which run and where
        raise ConfigError(f"ckpt_path={ckpt} was written under MLflow run {run_id}, which the store {uri} does not "
                          f"hold; resume with the store it was logged to (SPADE_HOME or paths.mlflow_tracking_uri), "
                          f"or {new_run}") from None
    name = run.info.run_name
    if run.info.status == "FINISHED":
        raise ConfigError(f"ckpt_path={ckpt} belongs to run {name!r} ({run_id}), which FINISHED: a resume would log "
                          f"into a finished run; {new_run}")
    params = run.data.params
    differ = [f"{key}: checkpoint's run {params[param]!r}, this config {str(get(cfg, key))!r}"
              for key, param in RESUME_KEYS
              if param in params and get(cfg, key) is not MISSING and params[param] != str(get(cfg, key))]
    if differ:
        raise ConfigError(f"ckpt_path={ckpt} is a checkpoint of run {name!r} ({run_id}), not of this experiment "
                          f"({'; '.join(differ)}); resume it with the config it was started with (+experiment="
                          f"{params.get('cfg/run_name', name)} and the same overrides), or {new_run}")


def check_expert_kind(cfg: DictConfig, expert: Any, info: dict[str, Any] | None) -> None:
    """DBC needs an unconditional expert, Cond-DBC a conditional one (``model.margin.expert``; the check is
    :meth:`MarginConfig.check_expert`, which the student runs on the loaded expert too)."""
    net_role = ((info or {}).get("config") or {}).get("role")
    config = margin_config(cfg)
    if net_role not in ("cond_expert", "uncond_expert") or config is None:
        return
    try:
        config.check_expert(net_role == "cond_expert", f"model.margin.expert_ckpt={expert}")
    except ExpertMismatchError as exc:
        raise ConfigError(str(exc)) from None
