"""``spade.evaluate``'s checks: the checkpoint's role, and its geometry against the data it is tested on."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from spade.config.checkpoint_checks import check_geometry, read_checkpoint
from spade.config.dataset_checks import check_data, check_datasets
from spade.config.file_checks import check_paths
from spade.config.store_checks import check_logger_store
from spade.config.values import check_bool, check_int, get
from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING, unset


def expert_sampling(cfg: DictConfig) -> dict[str, object]:
    """``expert_sampling``'s settings that are set (not null): the hyperparameters an expert checkpoint is loaded
    with instead of its own."""
    settings = get(cfg, "expert_sampling")
    if settings in (MISSING, None):
        return {}
    return {k: v for k, v in dict(settings).items() if v is not None}


def check_expert_sampling(cfg: DictConfig, ckpt: object, info: dict) -> None:
    """``expert_sampling.*``: only for an expert, a known sampler, steps within the expert's timesteps, K >= 2."""
    settings = expert_sampling(cfg)
    unknown = sorted(set(settings) - {"sampler", "num_inference_steps", "test_samples", "guidance_scale"})
    if unknown:
        raise ConfigError(f"expert_sampling.{unknown[0]} is not a sampling setting; valid: sampler, "
                          "num_inference_steps, test_samples, guidance_scale")
    if not settings:
        return
    if info.get("role") != "expert":
        raise ConfigError(f"expert_sampling sets how an expert samples, and ckpt_path={ckpt} is a "
                          f"{info.get('role')}: pass an expert checkpoint, or leave expert_sampling null")
    if "sampler" in settings and settings["sampler"] not in ("ddim", "ddpm"):
        raise ConfigError(f"expert_sampling.sampler={settings['sampler']!r} is not a sampler; valid: ddim, ddpm")
    check_int(cfg, "expert_sampling.num_inference_steps", 1, 1000, none_ok=True,
              fix=": denoising steps, e.g. expert_sampling.num_inference_steps=100 (null: the expert's own)")
    check_int(cfg, "expert_sampling.test_samples", 2, 64, none_ok=True,
              fix=": samples per test instance, e.g. expert_sampling.test_samples=4 (null: the expert's own)")
    scale = settings.get("guidance_scale")
    if scale is not None:
        from spade.models.modelfile import load_checkpoint  # heavy: only with guidance asked for

        hparams = load_checkpoint(Path(str(ckpt)), mmap=True).get("hyper_parameters") or {}
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0 <= scale <= 20:
            raise ConfigError(f"expert_sampling.guidance_scale={scale!r} is not a number in [0, 20]; e.g. "
                              "expert_sampling.guidance_scale=2 (null: the expert's own)")
        if scale != 1 and not hparams.get("cond_dropout"):
            raise ConfigError(f"expert_sampling.guidance_scale={scale} needs an expert trained with "
                              f"model.cond_dropout > 0, and ckpt_path={ckpt} was not: train one (e.g. "
                              "+experiment=teacher_cfg_L), or leave expert_sampling.guidance_scale null")


def validate_evaluate_config(cfg: DictConfig) -> None:
    """``spade.evaluate``'s checks: the checkpoint's role, and its geometry against the data it is tested on."""
    check_paths(cfg)
    check_int(cfg, "seed", 0, 2**32 - 1, fix=", e.g. seed=42")
    # source_seed is logged as the run's cfg/seed only when the test has finished: a bad one failed after a whole
    # evaluation and left a FINISHED run
    check_int(cfg, "source_seed", 0, 2**32 - 1, none_ok=True,
               fix=": the seed of the training run the checkpoint comes from (null: none)")
    for key in ("open_loop", "closed_loop"):
        check_bool(cfg, key)
    from spade.config.drive_checks import check_drive_config

    check_drive_config(cfg)  # drive.* typed and ranged, and something to evaluate, before any run opens
    check_int(cfg, "mcap_instances", 1, fix=", e.g. mcap_instances=64")
    ckpt = get(cfg, "ckpt_path")
    fix = "pass a student or expert checkpoint written by python -m spade.train"
    if ckpt in (MISSING, None, "", "???"):
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
    if get(cfg, "closed_loop") not in (MISSING, None, False) and info.get("role") != "student":
        raise ConfigError(f"closed_loop=true drives a planner, and ckpt_path={ckpt} is an {info.get('role')}: pass a "
                          "student checkpoint, or leave closed_loop=false (an expert's test has no closed loop)")
    check_expert_sampling(cfg, ckpt, info)
    check_logger_store(cfg)
    check_data(cfg)
    # the test set alone is read (the validation split of data.train_dir stands in only without a test_dir)
    scored = ("test",) if not unset(get(cfg, "data.test_dir")) else ("train",)
    check_datasets(cfg, scored)
    check_geometry("ckpt_path", ckpt, info, cfg, tuple(f"{name}_dir" for name in scored))
