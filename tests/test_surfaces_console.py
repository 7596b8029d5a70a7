"""Issue 48, item 6 (part): one progress line per stage on the console, not a bar per validation loader; the
annotate summary warns when a test part has few scenarios, with the uncertainty that implies."""

from __future__ import annotations

from pathlib import Path


def test_the_console_shows_no_bar_per_validation_loader(capsys) -> None:
    import lightning as L
    import torch
    from lightning.pytorch.demos.boring_classes import BoringModel, RandomDataset
    from torch.utils.data import DataLoader

    from spade.utils.console import stage_progress_bar

    class TwoLoaders(BoringModel):
        def validation_step(self, batch, batch_idx, dataloader_idx=0):  # type: ignore[no-untyped-def]
            return super().validation_step(batch, batch_idx)

        def val_dataloader(self):  # type: ignore[no-untyped-def]
            return [DataLoader(RandomDataset(32, 8)), DataLoader(RandomDataset(32, 8))]

    bar = stage_progress_bar(refresh_rate=1)
    trainer = L.Trainer(max_epochs=2, limit_train_batches=4, callbacks=[bar], logger=False,
                        enable_checkpointing=False, enable_model_summary=False, accelerator="cpu")
    torch.manual_seed(0)
    trainer.fit(TwoLoaders())
    captured = capsys.readouterr()
    err = captured.out + captured.err
    assert "Epoch 1" in err and "Validation" not in err and "Sanity Checking" not in err
    assert type(stage_progress_bar(enabled=False)).__name__ == "Callback"  # trainer.enable_progress_bar=false


def test_a_small_test_part_gets_a_warning_with_its_uncertainty() -> None:
    from spade.annotation.run import FEW_SCENARIOS, few_scenarios_warning, is_test_part

    text = few_scenarios_warning(10, True)
    assert text and "only 10 scenarios" in text and "+-31 percentage points" in text
    assert few_scenarios_warning(FEW_SCENARIOS, True) is None and few_scenarios_warning(10, False) is None
    assert is_test_part({"split": "test"}, None, Path("data/x")) and is_test_part({}, None, Path("data/own_test"))
    assert not is_test_part({}, None, Path("data/own_train"))
