"""``spade.evaluate``'s checks: its options built once (:func:`evaluate_options`), then the checkpoint's role,
and its geometry against the data it is tested on (:func:`check_evaluate`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar

from omegaconf import DictConfig

from spade.config.checkpoint_checks import check_data_geometry, read_checkpoint
from spade.config.dataset_checks import DataSources, ScaleOptions, check_data, check_datasets
from spade.config.file_checks import PathOptions
from spade.config.options import DataOptions, read_options
from spade.config.store_checks import StoreOptions, check_store
from spade.utils.errors import ConfigError
from spade.utils.option_checks import check_bool_value, check_int_value, unset
from spade.config.drive_checks import check_drive_config


@dataclass(frozen=True)
class ExpertSampling:
    """``expert_sampling.*``: the hyperparameters an expert checkpoint is loaded with instead of its own (None:
    the expert's own)."""

    sampler: str | None = None
    num_inference_steps: int | None = None
    test_samples: int | None = None
    guidance_scale: float | None = None

    def __post_init__(self) -> None:
        if self.sampler is not None and self.sampler not in ("ddim", "ddpm"):
            raise ConfigError(f"expert_sampling.sampler={self.sampler!r} is not a sampler; valid: ddim, ddpm")
        check_int_value("expert_sampling.num_inference_steps", self.num_inference_steps, 1, 1000, none_ok=True,
                        fix=": denoising steps, e.g. expert_sampling.num_inference_steps=100 (null: the expert's "
                            "own)")
        check_int_value("expert_sampling.test_samples", self.test_samples, 2, 64, none_ok=True,
                        fix=": samples per test instance, e.g. expert_sampling.test_samples=4 (null: the expert's own)")
        scale = self.guidance_scale
        if scale is not None and (isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0 <= scale <= 20):
            raise ConfigError(f"expert_sampling.guidance_scale={scale!r} is not a number in [0, 20]; e.g. "
                              "expert_sampling.guidance_scale=2 (null: the expert's own)")

    @classmethod
    def from_settings(cls, settings: Any) -> ExpertSampling:
        """From the ``expert_sampling`` group (null: none set); a key that is no sampling setting is refused."""
        settings = dict(settings or {})
        unknown = sorted(set(settings) - {f.name for f in fields(cls)})
        if unknown:
            raise ConfigError(f"expert_sampling.{unknown[0]} is not a sampling setting; valid: sampler, "
                              "num_inference_steps, test_samples, guidance_scale")
        return cls(**settings)

    @property
    def settings(self) -> dict[str, Any]:
        """The settings that are set (not null), as :func:`spade.evaluate.load_module` takes them."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


@dataclass(frozen=True)
class EvaluateRun:
    """``spade.evaluate``'s own keys (the config's top level)."""

    node: ClassVar[str] = ""

    ckpt_path: Any = None
    seed: int = 42
    source_seed: int | None = None  # the seed of the training run the checkpoint comes from (null: none)
    open_loop: bool | None = True
    closed_loop: bool | None = False
    mcap_instances: int = 64
    expert_sampling: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        check_int_value("seed", self.seed, 0, 2**32 - 1, fix=", e.g. seed=42")
        # source_seed is logged as the run's cfg/seed only when the test has finished: a bad one failed after a
        # whole evaluation and left a FINISHED run
        check_int_value("source_seed", self.source_seed, 0, 2**32 - 1, none_ok=True,
                        fix=": the seed of the training run the checkpoint comes from (null: none)")
        for key in ("open_loop", "closed_loop"):
            check_bool_value(key, getattr(self, key))
        check_int_value("mcap_instances", self.mcap_instances, 1, fix=", e.g. mcap_instances=64")


@dataclass(frozen=True)
class EvaluateOptions:
    """Every option of a ``spade.evaluate`` config its checks read, one typed object per config node."""

    paths: PathOptions
    run: EvaluateRun
    sampling: ExpertSampling
    store: StoreOptions
    data: DataOptions
    scale: ScaleOptions
    sources: DataSources


def evaluate_options(cfg: DictConfig) -> EvaluateOptions:
    """:class:`EvaluateOptions` from the composed config; a bad value is one line (:class:`ConfigError`)."""
    paths = read_options(cfg, PathOptions)
    run = read_options(cfg, EvaluateRun)
    check_drive_config(cfg)  # drive.* typed and ranged, and something to evaluate, before any run opens
    return EvaluateOptions(paths, run, ExpertSampling.from_settings(run.expert_sampling),
                           read_options(cfg, StoreOptions), read_options(cfg, DataOptions),
                           read_options(cfg, ScaleOptions), read_options(cfg, DataSources))


def check_expert_sampling(sampling: ExpertSampling, ckpt: object, info: dict) -> None:
    """``expert_sampling`` only for an expert, and guidance only for one trained with condition dropout."""
    if not sampling.settings:
        return
    if info.get("role") != "expert":
        raise ConfigError(f"expert_sampling sets how an expert samples, and ckpt_path={ckpt} is a "
                          f"{info.get('role')}: pass an expert checkpoint, or leave expert_sampling null")
    scale = sampling.guidance_scale
    if scale is not None and scale != 1:
        from spade.models.modelfile import load_checkpoint  # heavy: only with guidance asked for

        hparams = load_checkpoint(Path(str(ckpt)), mmap=True).get("hyper_parameters") or {}
        if not hparams.get("cond_dropout"):
            raise ConfigError(f"expert_sampling.guidance_scale={scale} needs an expert trained with "
                              f"model.cond_dropout > 0, and ckpt_path={ckpt} was not: train one (e.g. "
                              "+experiment=teacher_cfg_L), or leave expert_sampling.guidance_scale null")


def check_evaluate(options: EvaluateOptions) -> None:
    """The checkpoint's role, and its geometry against the data it is tested on."""
    ckpt = options.run.ckpt_path
    fix = "pass a student or expert checkpoint written by python -m spade.train"
    if ckpt in (None, "", "???"):
        raise ConfigError(f"ckpt_path is not set; {fix} (ckpt_path=PATH)")
    path = Path(str(ckpt))
    if not path.exists():
        raise ConfigError(f"ckpt_path={ckpt} does not exist; {fix}")
    if path.is_dir():
        raise ConfigError(f"ckpt_path={ckpt} is a directory, not a checkpoint file; {fix}")
    info = read_checkpoint("ckpt_path", ckpt, path, fix)
    if info.get("role") not in ("student", "expert"):
        raise ConfigError(f"ckpt_path={ckpt} is not a SPADE student or expert checkpoint (role "
                          f"{info.get('role')!r}); {fix}")
    if options.run.closed_loop not in (None, False) and info.get("role") != "student":
        raise ConfigError(f"closed_loop=true drives a planner, and ckpt_path={ckpt} is an {info.get('role')}: pass a "
                          "student checkpoint, or leave closed_loop=false (an expert's test has no closed loop)")
    check_expert_sampling(options.sampling, ckpt, info)
    check_store(options.store)
    check_data(options.sources, options.scale, None)
    # the test set alone is read (the validation split of data.train_dir stands in only without a test_dir)
    scored = ("test",) if not unset(options.sources.test_dir) else ("train",)
    check_datasets(options.sources, scored)
    check_data_geometry("ckpt_path", ckpt, info, options.sources, tuple(f"{name}_dir" for name in scored))


def validate_evaluate_config(cfg: DictConfig) -> EvaluateOptions:
    """``spade.evaluate``'s checks (:func:`evaluate_options`, then :func:`check_evaluate`); its options."""
    options = evaluate_options(cfg)
    check_evaluate(options)
    return options
