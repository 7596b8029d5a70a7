"""``spade.critic``'s checks, before any model or test set is loaded and before any MLflow run: the expert and
the optional student (role, kind, geometry), the margin's options, the test set it scores, the numbers of its
measurement, the store and the results folder."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from omegaconf import DictConfig

from spade.config.checkpoint_checks import check_checkpoint, check_geometry, expert_timesteps
from spade.config.dataset_checks import check_existing_dataset, check_folder_path
from spade.config.options import DataOptions, read_options
from spade.config.file_checks import check_path_value, check_paths, check_writable
from spade.config.store_checks import check_logger_store
from spade.utils.errors import ConfigError
from spade.utils.option_checks import check_bool_value, check_int_value, unset
from spade.config.preflight import check_expert_kind, margin_config
from spade.deploy.outputs import replace_refusal


@dataclass(frozen=True)
class CriticOptions:
    """``spade.critic``'s own options (conf/critic.yaml): the checkpoints, the seed and the results folder."""

    node: ClassVar[str] = ""
    ckpt_path: Any = None
    student_ckpt: Any = None
    seed: int = 0
    output_dir: Any = None  # null: no page
    overwrite: bool | None = False

    def __post_init__(self) -> None:
        check_int_value("seed", self.seed, 0, 2**32 - 1, fix=", e.g. seed=0")
        check_bool_value("overwrite", self.overwrite)


#: The most noise/timestep draws the critic measures per instance (``critic.bands`` x ``critic.draws_per_band``): its
#: time grows with them (the default, 5 x 2, takes seconds on a CPU; 100000 bands ran for minutes).
MAX_DRAWS = 200


@dataclass(frozen=True)
class CriticMeasure:
    """``critic.*``: the numbers of the critic's measurement."""

    node: ClassVar[str] = "critic"
    max_instances: int | None = 256  # null: the whole test set
    draws_per_band: int = 2
    bands: int = 5
    batch_size: int = 32
    expert_samples: int = 4  # 0: no planner figures

    def __post_init__(self) -> None:
        check_int_value("critic.max_instances", self.max_instances, 1, none_ok=True, fix=" (null: the whole test set)")
        check_int_value("critic.draws_per_band", self.draws_per_band, 1, fix=", e.g. critic.draws_per_band=2")
        check_int_value("critic.bands", self.bands, 1, fix=", e.g. critic.bands=5")
        check_int_value("critic.batch_size", self.batch_size, 1, fix=", e.g. critic.batch_size=32")
        check_int_value("critic.expert_samples", self.expert_samples, 0,
                        fix=" (0: no planner figures; 2 or more: K samples per instance)")
        if self.expert_samples == 1:
            raise ConfigError("critic.expert_samples=1: two samples at least measure the spread; set it to 0 (no "
                              "planner figures) or 2 or more (e.g. 4)")


@dataclass(frozen=True)
class CriticTestSet:
    """``data.test_dir`` and ``data.test_shape``: the test set the critic scores (no training set is needed)."""

    node: ClassVar[str] = "data"
    test_dir: Any = None
    test_shape: str | None = None


def validate_critic_config(cfg: DictConfig) -> CriticOptions:
    """``spade.critic``'s checks: every bad input is one line naming the key, its value and the fix, before the
    expert is loaded (a garbage store failed after a minute of measuring; a student given as the expert, a missing
    test set or ``critic.bands=0`` with a traceback); returns the command's own options."""
    check_paths(cfg)
    options = read_options(cfg, CriticOptions)
    fix = ("pass a diffusion expert checkpoint (python -m spade.train +experiment=cond_expert_L, or "
           "spade/models/weights/)")
    ckpt = options.ckpt_path
    if unset(ckpt):
        raise ConfigError(f"ckpt_path is not set; {fix} (ckpt_path=PATH)")
    margin = margin_config(cfg)  # model.margin's options, by MarginConfig's own checks
    info = check_checkpoint("ckpt_path", ckpt, "expert", fix)
    _check_test_set(read_options(cfg, CriticTestSet))
    check_expert_kind(cfg, ckpt, info)  # Cond-DBC needs a conditional expert, DBC an unconditional one
    check_geometry("ckpt_path", ckpt, info, cfg, ("test_dir",))
    student = options.student_ckpt
    if not unset(student):
        info = check_checkpoint("student_ckpt", student, "student",
                                 "pass a student checkpoint written by python -m spade.train, or student_ckpt=null")
        check_geometry("student_ckpt", student, info, cfg, ("test_dir",))
    measure = read_options(cfg, CriticMeasure)
    _check_timesteps(measure, ckpt, margin)
    read_options(cfg, DataOptions)  # data.target_width_px, the markers' encoding, the loader's numbers
    check_logger_store(cfg)
    out = options.output_dir
    if out is not None:
        check_path_value("output_dir", out, "set output_dir to a folder for the results page (null: no page)")
        if Path(str(out)).expanduser().is_file():
            raise ConfigError(f"output_dir={out} is a file; give a folder for the results page (null: no page)")
        check_writable("output_dir", Path(str(out)).expanduser() / "page.md",
                       "give a folder you can write for the results page (null: no page)")
        if margin is not None:
            from spade.training.critic import page_stem
            for suffix in (".md", ".png"):
                stem = page_stem(str(ckpt), margin, not unset(student))
                path = Path(str(out)).expanduser() / (stem + suffix)
                refusal = replace_refusal("output_dir", path, options.overwrite is True,
                                          label=f"output_dir={out}: {path}")
                if refusal is not None:
                    raise ConfigError(refusal)
    return options


def _check_timesteps(measure: CriticMeasure, ckpt: Any, margin: Any) -> None:
    """The margin's timestep range within the expert's training timesteps T (``model.margin.t_max`` beyond T
    failed with a traceback once the expert was loaded), and the critic's bands and draws bounded: at most one
    band per timestep of the range, and at most :data:`MAX_DRAWS` draws per instance."""
    T = expert_timesteps(str(ckpt))
    t_min = int(getattr(margin, "t_min", 0) or 0)
    t_max = getattr(margin, "t_max", None)
    if t_max is not None and t_max > T:
        raise ConfigError(f"model.margin.t_max={t_max} exceeds the {T} training timesteps of the expert "
                          f"(ckpt_path={ckpt}, T={T}); set model.margin.t_max <= {T}, or null for all of them")
    if t_min >= T:
        raise ConfigError(f"model.margin.t_min={t_min} is not below the {T} training timesteps of the expert "
                          f"(ckpt_path={ckpt}, T={T}); set model.margin.t_min < {T}, e.g. 0")
    width = (t_max if t_max is not None else T) - t_min
    bands, draws = measure.bands, measure.draws_per_band
    if bands > width:
        raise ConfigError(f"critic.bands={bands} exceeds the {width} timesteps of the margin's range "
                          f"[{t_min}, {t_min + width}) (the expert's T={T}): a band holds one timestep at least; "
                          f"set critic.bands <= {min(width, MAX_DRAWS)}, e.g. critic.bands=5")
    if bands * draws > MAX_DRAWS:
        raise ConfigError(f"critic.bands={bands} x critic.draws_per_band={draws} = {bands * draws} draws per "
                          f"instance exceed the limit of {MAX_DRAWS} (the critic's time grows with them); lower "
                          f"them, e.g. critic.bands=5 critic.draws_per_band=2")


def _check_test_set(test_set: CriticTestSet) -> None:
    """The critic scores the test set alone (``data.test_dir``): it must hold a dataset, opened with the loaders'
    checks (files, checksums, finite values), and instances of ``data.test_shape``. No training set is needed."""
    test_dir = test_set.test_dir
    check_folder_path("data.test_dir", test_dir)
    fix = ("pass the test set the expert is judged on (data.test_dir=DIR), or build it first (any `python -m "
           "spade.train +experiment=...` of this scale and data generates it, or `python -m spade.annotate "
           "preset=test out_dir=DIR`)")
    if unset(test_dir):
        raise ConfigError(f"data.test_dir is not set; {fix}")
    root = Path(str(test_dir)).expanduser()
    if not (root / "manifest.json").is_file():
        raise ConfigError(f"data.test_dir={test_dir} holds no dataset; {fix}")
    dataset = check_existing_dataset("data.test_dir", root)
    shape = test_set.test_shape
    if shape is not None and dataset is not None:
        shapes = sorted(set(dataset.labels("shape")))
        if shape not in shapes:
            raise ConfigError(f"data.test_shape={shape!r}: {test_dir} holds no instances of that shape (it holds "
                              f"{shapes}); set data.test_shape to one of them, or data.test_shape=null for all")
