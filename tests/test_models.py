"""Tests of the SPADE networks: parameter budgets, shapes, conditioning, errors and the builders (spade.models.builders)."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from spade.models.builders import ROLES, build_model, count_parameters, model_from_config, presets
from spade.models.cond_expert import CondExpertUNet, build_cond_expert
from spade.models.paper_sizes import PAPER_COND_EXPERT_PARAMETERS, PAPER_PARAMETER_COUNTS
from spade.models.student import STUDENT_PRESETS, StudentUNet, build_student
from spade.models.uncond_expert import build_uncond_expert

# Exact counts of the chosen presets (regression guard on the widths); the paper's figures are in PAPER_PARAMETER_COUNTS.
STUDENT_COUNTS = {"small": 118_165, "medium": 1_926_209, "large": 31_114_785}
COND_EXPERT_PAPER = PAPER_COND_EXPERT_PARAMETERS


def _meta(builder, *args):
    with torch.device("meta"):
        return builder(*args)


@pytest.mark.parametrize("size", ["small", "medium", "large"])
def test_student_parameter_count_matches_paper(size: str) -> None:
    model = build_student(size)  # built for real: trainable-parameter flags and BN buffers as in training
    n = count_parameters(model)
    assert n == STUDENT_COUNTS[size]
    assert abs(n - PAPER_PARAMETER_COUNTS[size]) / PAPER_PARAMETER_COUNTS[size] < 0.03
    # BatchNorm running statistics are buffers, not trainable parameters.
    assert count_parameters(model, trainable_only=False) == n


def test_student_skipp_block_structure() -> None:
    model = StudentUNet(3, 1, (16, 32, 64))
    # SKIPP's own small tuple (64-32-16 mirrored) gives about twice the paper's small count: 230,593.
    assert count_parameters(model) == 230_593
    block = model.downs[0]
    assert isinstance(block.transform, nn.Conv2d) and block.transform.kernel_size == (4, 4) and block.transform.stride == (2, 2)
    assert isinstance(model.ups[0].transform, nn.ConvTranspose2d)
    assert model.ups[0].conv1.in_channels == 2 * 64  # concatenated skip
    assert model.head.kernel_size == (1, 1) and model.head.out_channels == 1


@pytest.mark.parametrize("size,hw", [("small", (32, 32)), ("small", (16, 24)), ("medium", (32, 48)), ("large", (64, 64))])
def test_student_output_shape(size: str, hw: tuple[int, int]) -> None:
    model = build_student(size).eval()
    with torch.no_grad():
        out = model(torch.rand(2, 3, *hw))
    assert out.shape == (2, 1, *hw)
    assert out.dtype == torch.float32


def test_student_bad_sizes_raise_clear_errors() -> None:
    with pytest.raises(ValueError, match="valid sizes.*large.*medium.*small"):
        build_student("huge")
    model = build_student("medium")
    with pytest.raises(ValueError, match="not divisible by 8"):
        model(torch.rand(1, 3, 36, 32))
    with pytest.raises(ValueError, match="channels"):
        model(torch.rand(1, 1, 32, 32))


def test_student_learns_one_instance() -> None:
    torch.manual_seed(0)
    model = build_student("small")
    x = torch.rand(4, 3, 16, 16)
    y = (torch.rand(4, 1, 16, 16) > 0.8).float()
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    losses = []
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny convolutions: one thread is fastest, and immune to a busy machine's oversubscription
    try:
        for _ in range(40):
            loss = nn.functional.binary_cross_entropy_with_logits(model(x), y)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
    finally:
        torch.set_num_threads(threads)
    assert losses[-1] < 0.5 * losses[0]


def test_cond_expert_paper_parameter_count() -> None:
    n = count_parameters(_meta(build_cond_expert, "paper"))
    assert abs(n - COND_EXPERT_PAPER) / COND_EXPERT_PAPER < 0.05


def test_cond_expert_tiny_is_small_and_shapes_hold() -> None:
    model = build_cond_expert("tiny").eval()
    assert count_parameters(model) < 100_000
    out = model(torch.randn(3, 1, 32, 32), torch.tensor([0, 10, 999]), torch.rand(3, 3, 32, 32))
    assert out.shape == (3, 1, 32, 32)
    small = build_cond_expert("small").eval()
    assert small(torch.randn(1, 1, 32, 32), torch.tensor([5]), torch.rand(1, 3, 32, 32)).shape == (1, 1, 32, 32)


def _cond_inputs(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(1, 1, 32, 32, generator=g)
    cond = torch.zeros(1, 3, 32, 32)
    cond[:, 0] = 0.5  # free space
    return x, torch.tensor([100]), cond


def test_film_output_depends_on_condition() -> None:
    torch.manual_seed(0)
    model = build_cond_expert("tiny").eval()
    x, t, cond = _cond_inputs()
    moved = cond.clone()
    moved[:, 0, 10:14, 10:14] = 1.0  # an obstacle appears
    with torch.no_grad():
        a, b = model(x, t, cond), model(x, t, moved)
    assert not torch.allclose(a, b)
    # The change is local: pixels next to the obstacle change more than pixels far from it.
    diff = (a - b).abs()[0, 0]
    assert diff[8:16, 8:16].mean() > diff[24:, 24:].mean()


def test_film_gradient_reaches_nearby_condition_pixels() -> None:
    torch.manual_seed(0)
    model = build_cond_expert("tiny").eval()
    x, t, cond = _cond_inputs()
    cond.requires_grad_(True)
    out = model(x, t, cond)
    out[0, 0, 20, 12].backward()
    g = cond.grad[0].abs().sum(0)
    assert g[20, 12] > 0  # the state pixel under the output pixel matters
    assert g[18:23, 10:15].sum() > 0
    # Per-pixel FiLM keeps positions: the neighbourhood dominates the same-size patch far away.
    assert g[18:23, 10:15].sum() > 10 * g[0:5, 27:32].sum()


def test_expert_output_depends_on_timestep() -> None:
    torch.manual_seed(0)
    cond_model = build_cond_expert("tiny").eval()
    x, _, cond = _cond_inputs()
    with torch.no_grad():
        assert not torch.allclose(cond_model(x, torch.tensor([1]), cond), cond_model(x, torch.tensor([900]), cond))
    uncond = build_uncond_expert("tiny").eval()
    x4 = torch.randn(1, 4, 16, 16)
    with torch.no_grad():
        assert not torch.allclose(uncond(x4, torch.tensor([1])), uncond(x4, torch.tensor([900])))


def test_cond_expert_rejects_mismatched_inputs() -> None:
    model = build_cond_expert("tiny")
    with pytest.raises(ValueError, match="must match x_t"):
        model(torch.randn(1, 1, 32, 32), torch.tensor([1]), torch.rand(1, 3, 16, 16))
    with pytest.raises(ValueError, match="cond has 4 channels"):
        model(torch.randn(1, 1, 32, 32), torch.tensor([1]), torch.rand(1, 4, 32, 32))
    with pytest.raises(ValueError, match="integer"):
        model(torch.randn(1, 1, 32, 32), torch.tensor([1.5]), torch.rand(1, 3, 32, 32))
    with pytest.raises(ValueError, match="timesteps must have shape"):
        model(torch.randn(2, 1, 32, 32), torch.tensor([1, 2, 3]), torch.rand(2, 3, 32, 32))
    with pytest.raises(ValueError, match="not divisible by 8"):
        build_cond_expert("small")(torch.randn(1, 1, 20, 20), torch.tensor([1]), torch.rand(1, 3, 20, 20))


def test_uncond_expert_paper_is_about_one_billion_on_meta() -> None:
    model = _meta(build_uncond_expert, "paper")
    assert next(model.parameters()).device.type == "meta"
    assert model.widths[0] == 128 and model.widths[-1] == 2048
    n = count_parameters(model)
    assert abs(n - 1e9) / 1e9 < 0.10


def test_uncond_expert_shapes() -> None:
    model = build_uncond_expert("tiny").eval()
    assert model(torch.randn(2, 4, 32, 32), torch.tensor([0, 999])).shape == (2, 4, 32, 32)
    small = build_uncond_expert("small").eval()
    assert small(torch.randn(1, 4, 32, 32), torch.tensor(3)).shape == (1, 4, 32, 32)  # scalar t broadcasts
    with pytest.raises(ValueError, match="unknown uncond_expert preset"):
        build_uncond_expert("giant")


def test_the_builders_build_every_cpu_preset_with_metadata() -> None:
    assert set(ROLES) == {"student", "cond_expert", "uncond_expert"}
    for role in ROLES:
        for preset in presets(role):
            big = (role, preset) in {("uncond_expert", "paper"), ("student", "large")}
            model = _meta(build_model, role, preset) if big else build_model(role, preset)
            cfg = model.config
            assert cfg["role"] == role and cfg["preset"] == preset
            assert cfg["in_channels"] == model.in_channels and cfg["out_channels"] == model.out_channels
            assert cfg["resolution_multiple"] >= 2
            if role != "student":
                assert hasattr(model, "condition_channels")
    assert build_model("student", "small").in_channels == 3 and build_model("student", "small").out_channels == 1
    assert build_model("cond_expert", "tiny").condition_channels == 3
    assert build_model("uncond_expert", "tiny").in_channels == 4
    with pytest.raises(ValueError, match="valid roles"):
        build_model("critic", "small")
    with pytest.raises(ValueError, match="valid presets"):
        build_model("student", "paper")


def test_model_from_config_round_trips_a_checkpoint() -> None:
    for role, preset in [("student", "small"), ("cond_expert", "tiny"), ("uncond_expert", "tiny")]:
        model = build_model(role, preset)
        clone = model_from_config(model.config)
        assert clone.config == model.config
        clone.load_state_dict(model.state_dict())  # strict: same architecture
    custom = CondExpertUNet(widths=(8, 16, 16), cond_widths=(8, 8, 8), time_dim=16)
    assert model_from_config(custom.config).config == custom.config
    with pytest.raises(ValueError, match="role"):
        model_from_config({"widths": [1, 2]})


def test_student_presets_are_sorted_by_size() -> None:
    counts = [count_parameters(_meta(build_student, s)) for s in ("small", "medium", "large")]
    assert counts == sorted(counts)
    assert set(STUDENT_PRESETS) == {"small", "medium", "large"}
