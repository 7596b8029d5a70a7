"""``spade.train``'s preflight: everything in a run's config that needs no training, before any MLflow run opens.

:func:`train_options` builds the run's options once, one typed object per config node, each checking itself as it
is built (:class:`TrainRun` and :class:`RegistryOptions`, the run's own keys; :class:`~spade.config.file_checks.
PathOptions`; :class:`~spade.config.store_checks.StoreOptions`; :class:`~spade.config.options.TrainerBudget`;
:class:`~spade.data.datamodule_options.DataOptions`, :class:`~spade.config.dataset_checks.ScaleOptions` and
:class:`~spade.config.dataset_checks.DataSources`; the model's :class:`~spade.training.module_options.StudentOptions`
or :class:`~spade.training.module_options.ExpertOptions`; the margin's :class:`~spade.training.margin.MarginConfig`:
the classes the modules themselves build). :func:`check_train` then checks, as functions of those options, what
crosses components: the store the run logs to, the data's folders and windows against the model, the metric it
optimises (which depends on the model's role), and every checkpoint the run names (``ckpt_path``,
``model.init_ckpt``, ``model.margin.expert_ckpt``): its role, its geometry against the data, the expert's kind
against the margin, and the run a resume would continue.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

from omegaconf import DictConfig

from spade.config.checkpoint_checks import check_checkpoint, check_data_geometry
from spade.config.dataset_checks import DataSources, ScaleOptions, check_data, check_datasets
from spade.config.file_checks import PathOptions
from spade.config.options import (
    DataOptions,
    ModelOptions,
    ModelSource,
    TrainerBudget,
    options_of_class,
    read_options,
)
from spade.config.store_checks import StoreOptions, check_store, store_path
from spade.training.expert_mismatch import ExpertMismatchError
from spade.utils.errors import ConfigError
from spade.utils.option_checks import check_bool_value, check_choice_value, check_int_value
from spade.deploy.mlflow_models import mlflow_client

if TYPE_CHECKING:
    from spade.training.margin import MarginConfig


@dataclass(frozen=True)
class TrainRun:
    """``spade.train``'s own keys (the config's top level): what it runs, the metric it optimises, the checkpoint
    it resumes."""

    node: ClassVar[str] = ""

    run_name: Any = None
    seed: int | None = None
    prerequisites: str = "train"  # train | error: a prerequisite that is not registered is trained, or refused
    train: bool | None = True
    test: bool | None = True
    test_untrained: bool | None = False
    closed_loop: bool | None = False
    optimized_metric: Any = None
    ckpt_path: Any = None

    def __post_init__(self) -> None:
        check_int_value("seed", self.seed, 0, 2**32 - 1, none_ok=True, fix=", e.g. seed=42")
        check_choice_value("prerequisites", self.prerequisites, ["train", "error"])
        for key in ("train", "test", "test_untrained", "closed_loop"):
            check_bool_value(key, getattr(self, key))
        metric = self.optimized_metric
        if metric is not None and (not isinstance(metric, str) or not metric.strip()):
            raise ConfigError(f"optimized_metric={metric!r} must be a metric name such as val/score_cm; set "
                              "optimized_metric=val/score_cm (a student) or val/loss (an expert)")
        if isinstance(self.ckpt_path, str) and not self.ckpt_path.strip():
            raise ConfigError("ckpt_path='' is empty; pass checkpoints/last.ckpt of an interrupted run to resume it, "
                              "or leave ckpt_path unset (ckpt_path=null) to start a new run")


@dataclass(frozen=True)
class RegistryOptions:
    """``registry.*``: a name prefix (a string, or null: nothing registered), ``promote`` a strict boolean
    (``maybe`` would have promoted the new version to @champion), ``tags`` a mapping."""

    node: ClassVar[str] = "registry"

    prefix: str | None = None
    promote: bool | None = False
    tags: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        check_bool_value("registry.promote", self.promote)
        prefix = self.prefix
        if prefix is not None and (not isinstance(prefix, str) or not prefix.strip()):
            raise ConfigError(f"registry.prefix={prefix!r} is not a model name prefix; set registry.prefix=NAME "
                              "(letters, digits, '-', '_') or registry.prefix=null to register nothing")
        if self.tags is not None and not isinstance(self.tags, Mapping):
            raise ConfigError(f"registry.tags={self.tags!r} is not a mapping; set registry.tags={{KEY: VALUE}} or "
                              "leave it {}")


@dataclass(frozen=True)
class TrainOptions:
    """Every option of a ``spade.train`` config the preflight checks, one typed object per config node, each
    checked as it is built (:func:`train_options`)."""

    paths: PathOptions
    run: TrainRun
    store: StoreOptions
    registry: RegistryOptions
    trainer: TrainerBudget
    data: DataOptions
    scale: ScaleOptions
    sources: DataSources
    model_source: ModelSource
    model: ModelOptions | None  # None: a class SPADE has no options for
    margin: MarginConfig | None  # a student's (or that of a model naming an expert checkpoint); None without one

    @property
    def role(self) -> str | None:
        return None if self.model is None else self.model.role


def train_options(cfg: DictConfig) -> TrainOptions:
    """:class:`TrainOptions` from the composed config; a bad value is one line (:class:`ConfigError`)."""
    paths = read_options(cfg, PathOptions)  # first: an empty paths.data_dir would generate datasets under the root
    run, store = read_options(cfg, TrainRun), read_options(cfg, StoreOptions)
    registry = read_options(cfg, RegistryOptions)
    trainer, data = read_options(cfg, TrainerBudget), read_options(cfg, DataOptions)
    scale, sources = read_options(cfg, ScaleOptions), read_options(cfg, DataSources)
    source = read_options(cfg, ModelSource)
    model_type = options_of_class(source._target_)
    model = None if model_type is None else read_options(cfg, model_type)
    guided = (model is not None and model.role == "student") or source.expert_ckpt is not None
    return TrainOptions(paths, run, store, registry, trainer, data, scale, sources, source, model,
                        margin_options(source.margin) if guided else None)


def check_train(options: TrainOptions) -> None:
    """What crosses components, before any MLflow run opens: the store, the data's folders and windows against the
    model, the metric the role logs, every checkpoint the run names, and the datasets already on disk."""
    check_store(options.store)
    check_data(options.sources, options.scale, options.model)
    check_optimized_metric(options)
    check_checkpoints(options)
    check_datasets(options.sources, options.sources.training_sets())


def validate_train_config(cfg: DictConfig) -> TrainOptions:
    """Every check of ``spade.train``'s config that needs no training (:func:`train_options`, then
    :func:`check_train`); raises :class:`ConfigError` (one line)."""
    options = train_options(cfg)
    check_train(options)
    return options


def validate_checkpoints(cfg: DictConfig) -> None:
    """The role, kind and geometry checks of every checkpoint a run names (``ckpt_path``, ``model.init_ckpt``,
    ``model.margin.expert_ckpt``), again after the prerequisites filled paths from the Model Registry: a
    fetched model passes the same checks as one given by path."""
    check_checkpoints(train_options(cfg))


def fit_metrics(options: TrainOptions) -> set[str] | None:
    """The metrics the configured module logs while it trains (what ``optimized_metric`` may name: it picks the
    best checkpoint, so a test metric would never be seen): ``val/`` + the validation figures
    (:class:`~spade.metrics.path_metrics.PathMetrics` without the planner, with its preference and FID keys), the
    role's losses, and a guided student's margin figures. None for a module this check does not know."""
    role = options.role
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
        if options.model_source.margin not in (None, {}):
            names |= {"train/loss_dm", "train/margin_active", "margin/active", "margin/value"}
    else:
        names |= {"val/loss", "train/loss"}
    return names


def check_optimized_metric(options: TrainOptions) -> None:
    """``optimized_metric`` names a metric the module logs while training (:func:`fit_metrics`): a misspelt one
    failed only after the first validation (the checkpoint callback monitors it), an epoch of work lost."""
    metric = options.run.optimized_metric
    if metric is None:
        return
    names = fit_metrics(options)
    if names is None or metric in names:
        return
    shown = sorted(n for n in names if n.startswith("val/"))
    raise ConfigError(f"optimized_metric={metric} is not a metric the {options.role} logs while training; set it to "
                      f"one of {', '.join(shown)} (or {', '.join(sorted(names - set(shown)))})")


def margin_options(options: Any) -> MarginConfig | None:
    """The ``model.margin`` group as a :class:`~spade.training.margin.MarginConfig` (None without a margin): its
    checks are MarginConfig's, reported as one line naming ``model.margin.<option>``."""
    from spade.training.margin import MarginConfig, MarginOptionError  # heavy: the margin imports Lightning

    if options is None:
        return None
    if not isinstance(options, Mapping):
        raise ConfigError(f"model.margin={options!r} is not a group of margin options; choose margin=none, "
                          "margin=dbc or margin=cond_dbc")
    try:
        return MarginConfig.from_options(options)
    except MarginOptionError as exc:
        raise ConfigError(exc.at("model.margin.")) from None


def margin_config(cfg: DictConfig) -> MarginConfig | None:
    """:func:`margin_options` of a command's ``model.margin`` (for the checks that take the config)."""
    return margin_options(read_options(cfg, ModelSource).margin)


def check_checkpoints(options: TrainOptions) -> None:
    """Every checkpoint the run names: its role, its geometry against the data, the expert's kind against the
    margin, and the run a resume would continue."""
    role, source, sources = options.role, options.model_source, options.sources
    train_data = ("train_dir", "test_dir")
    ckpt = options.run.ckpt_path
    if ckpt is not None and role is not None:
        fix = "pass checkpoints/last.ckpt of an interrupted run of this experiment (under its logs/runs/ folder)"
        info = check_checkpoint("ckpt_path", ckpt, role, fix)
        check_data_geometry("ckpt_path", ckpt, info, sources, train_data)
        check_resume(options, ckpt, info)
    init = source.init_ckpt
    if init is not None:
        wanted = role or "student"  # a student starts from a student, an expert from an expert
        info = check_checkpoint("model.init_ckpt", init, wanted,
                                f"pass a {wanted} checkpoint (the pretrained {wanted} the run fine-tunes)")
        check_data_geometry("model.init_ckpt", init, info, sources, train_data)
    expert = source.expert_ckpt
    if expert is not None:
        info = check_checkpoint("model.margin.expert_ckpt", expert, "expert",
                                "pass an expert checkpoint (from a cond_expert_* or uncond_expert_* experiment), or "
                                "leave it null so that the experiment's requires.expert finds or trains one")
        check_data_geometry("model.margin.expert_ckpt", expert, info, sources, train_data)
        check_expert_matches(options.margin, expert, info)
    teacher = sources.unlabelled_teacher
    if teacher not in (None, ""):
        if sources.unlabelled_labels is not True or sources.folder("unlabelled") is None:
            raise ConfigError(f"data.unlabelled_teacher={teacher} labels the unlabelled states: set "
                              "data.unlabelled_dir and data.unlabelled_labels=true with it (or drop it)")
        info = check_checkpoint("data.unlabelled_teacher", teacher, "expert",
                                "pass a conditional expert checkpoint (a cond_expert_* or teacher_* run's best)")
        check_data_geometry("data.unlabelled_teacher", teacher, info, sources, train_data)


def resume_keys(options: TrainOptions) -> dict[tuple[str, str], Any]:
    """What a resumed run must share with the run its checkpoint was written under: (config key, MLflow
    parameter) -> this config's value (None: not set, not compared)."""
    size = options.model.size if options.role == "student" else None  # type: ignore[union-attr]
    return {("run_name", "cfg/run_name"): options.run.run_name, ("seed", "cfg/seed"): options.run.seed,
            ("model.size", "cfg/model/size"): size, ("scale.name", "cfg/scale/name"): options.scale.name}


def check_resume(options: TrainOptions, ckpt: Any, info: dict[str, Any] | None) -> None:
    """``ckpt_path`` resumes the MLflow run the checkpoint was written under. Refused before any work (so that no
    command changes a run it did not start): a run this store does not hold, a FINISHED run, and a checkpoint of
    another row, seed, size or scale (each named with both values)."""
    if options.run.train is not True or not ckpt:
        return  # train=false: the checkpoint's weights are tested, nothing is resumed
    run_id = (info or {}).get("mlflow_run_id")
    uri = options.store.uri
    if not run_id or uri is None:
        return  # written without MLflow, or MLflow off: nothing to continue
    new_run = ("start a new run instead (drop ckpt_path" + (", or start from its weights with model.init_ckpt="
                                                              f"{ckpt}" if options.role == "student" else "") + ")")
    path = store_path(uri)
    if path is not None and not path.exists():
        raise ConfigError(f"ckpt_path={ckpt} was written under MLflow run {run_id}, but there is no store at {uri}; "
                          f"resume with the store it was logged to (SPADE_HOME or paths.mlflow_tracking_uri), or "
                          f"{new_run}")
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
    differ = [f"{key}: checkpoint's run {params[param]!r}, this config {str(value)!r}"
              for (key, param), value in resume_keys(options).items()
              if param in params and value is not None and params[param] != str(value)]
    if differ:
        raise ConfigError(f"ckpt_path={ckpt} is a checkpoint of run {name!r} ({run_id}), not of this experiment "
                          f"({'; '.join(differ)}); resume it with the config it was started with (+experiment="
                          f"{params.get('cfg/run_name', name)} and the same overrides), or {new_run}")


def check_expert_matches(margin: MarginConfig | None, expert: Any, info: dict[str, Any] | None) -> None:
    """DBC needs an unconditional expert, Cond-DBC a conditional one (``model.margin.expert``; the check is
    :meth:`MarginConfig.check_expert`, which the student runs on the loaded expert too)."""
    net_role = ((info or {}).get("config") or {}).get("role")
    if net_role not in ("cond_expert", "uncond_expert") or margin is None:
        return
    try:
        margin.check_expert(net_role == "cond_expert", f"model.margin.expert_ckpt={expert}")
    except ExpertMismatchError as exc:
        raise ConfigError(str(exc)) from None


def check_expert_kind(cfg: DictConfig, expert: Any, info: dict[str, Any] | None) -> None:
    """:func:`check_expert_matches` of a command's ``model.margin`` (for the checks that take the config)."""
    check_expert_matches(margin_config(cfg), expert, info)
