"""The configurables' typed options check themselves, the model's role comes from its class, and each command
loads only its own checks."""

from __future__ import annotations

import subprocess
import sys

import pytest
from omegaconf import OmegaConf

from spade.config.options import (
    DataOptions,
    ExpertOptions,
    StudentOptions,
    TrainerBudget,
    model_role,
    read_options,
)
from spade.utils.errors import ConfigError


def test_each_option_is_refused_in_one_line_naming_its_full_key() -> None:
    cases = [
        (lambda: StudentOptions(bc_pos_weight=0), "model.bc_pos_weight=0 is out of range"),
        (lambda: StudentOptions(size="huge"), "model.size='huge' is not one of"),
        (lambda: ExpertOptions(sampler="euler"), "model.sampler='euler' is not one of"),
        (lambda: ExpertOptions(ema_decay=1.0), "model.ema_decay=1 is out of range"),
        (lambda: ExpertOptions(test_samples=1), "model.test_samples=1 is out of range"),
        (lambda: DataOptions(batch_size=0), "data.batch_size=0 is out of range"),
        (lambda: DataOptions(target_width_px=2), "data.target_width_px=2 is not an odd number"),
        (lambda: DataOptions(encoding="square"), "data.encoding='square' is not a marker encoding"),
        (lambda: TrainerBudget(max_epochs="abc"), "trainer.max_epochs='abc' is not an integer"),
        (lambda: TrainerBudget(max_epochs=-1, max_steps=-1), "never stop"),
        (lambda: TrainerBudget(limit_val_batches=1.5), "trainer.limit_val_batches=1.5 must be a fraction"),
    ]
    for build, message in cases:
        with pytest.raises(ConfigError) as err:
            build()
        assert message in str(err.value) and "\n" not in str(err.value)
    StudentOptions(bc_pos_weight=None)
    ExpertOptions(preset="tiny")
    TrainerBudget(max_epochs=-1, max_steps=10)


def test_options_are_read_from_the_composed_node_with_interpolations_resolved() -> None:
    cfg = OmegaConf.create({"scale": {"batch_size": 0}, "data": {"batch_size": "${scale.batch_size}",
                                                                 "train_dir": "/somewhere", "_target_": "x.Y"}})
    with pytest.raises(ConfigError, match=r"data.batch_size=0 is out of range"):
        read_options(cfg, DataOptions)
    assert read_options(OmegaConf.create({}), TrainerBudget) == TrainerBudget()


def test_the_models_role_comes_from_its_class() -> None:
    def role(target: str) -> str | None:
        return model_role(OmegaConf.create({"model": {"_target_": target}}))

    assert role("spade.training.student_module.StudentModule") == "student"
    assert role("spade.training.expert_module.ExpertModule") == "expert"
    assert role("tests_only.NotAStudentModule") is None  # the spelling of the path says nothing
    assert role("collections.OrderedDict") is None


def test_importing_the_train_command_loads_no_other_commands_checks() -> None:
    code = ("import sys, spade.train; ms = [m for m in sys.modules if m.startswith('spade')]; "
            "print(len(ms)); print(' '.join(ms))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert int(out[0]) <= 45, out[1]
    assert not any(m.endswith(("sketch_checks", "plan_checks", "export_checks")) for m in out[1].split())


def test_the_constructors_refuse_with_their_options_checks() -> None:
    """The data module and the LightningModules build their options dataclass: the preflight's one-line message,
    before anything is built."""
    from spade.data.datamodule import PathDataModule
    from spade.training.expert_module import ExpertModule
    from spade.training.student_module import StudentModule

    cases = [
        (lambda: StudentModule(size="small", bc_pos_weight=0), "model.bc_pos_weight=0 is out of range"),
        (lambda: ExpertModule(preset="tiny", sampler="euler"), "model.sampler='euler' is not one of"),
        (lambda: ExpertModule(preset="tiny", test_samples=1), "model.test_samples=1 is out of range"),
        (lambda: PathDataModule(None, batch_size=0), "data.batch_size=0 is out of range"),
        (lambda: PathDataModule(None, target_width_px=2), "data.target_width_px=2 is not an odd number"),
        (lambda: PathDataModule(None, encoding="square"), "data.encoding='square' is not a marker encoding"),
        (lambda: PathDataModule(None, shuffle_buffer=4), "data.shuffle_buffer is not an option of the data module"),
    ]
    for build, message in cases:
        with pytest.raises(ConfigError) as err:
            build()
        assert message in str(err.value) and "\n" not in str(err.value)


def test_a_new_data_option_is_one_field_of_data_options(monkeypatch) -> None:
    """The code map's example: a field added to DataOptions reaches the data module (``self.options``) and its
    check refuses a bad value, with no change to PathDataModule."""
    from dataclasses import dataclass

    import spade.data.datamodule as datamodule
    from spade.data.datamodule_options import DataOptions
    from spade.utils.option_checks import check_int_value

    @dataclass(frozen=True)
    class WithShuffle(DataOptions):
        shuffle_buffer: int = 0

        def __post_init__(self) -> None:
            super().__post_init__()
            check_int_value("data.shuffle_buffer", self.shuffle_buffer, 0)

    monkeypatch.setattr(datamodule, "DataOptions", WithShuffle)
    assert datamodule.PathDataModule(None, shuffle_buffer=64).options.shuffle_buffer == 64
    with pytest.raises(ConfigError, match="data.shuffle_buffer=-1 is out of range"):
        datamodule.PathDataModule(None, shuffle_buffer=-1)
