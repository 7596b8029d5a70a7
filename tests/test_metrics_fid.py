"""FID: reference agreement, batch-split invariance, the default extractor sees path shape (validity against known
shape changes, with stated margins), the random conv extractor's drawing sensitivity, clear errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import linalg

from spade.metrics.features import DEFAULT_RANDCONV_SHA256, RandomConvFeatures, build_feature_extractor
from spade.metrics.fid import FID, frechet_distance
from spade.metrics.shape_features import DEFAULT_SHAPE_SHA256, SHAPE_WEIGHTS_FILE, ShapeFeatures, weights_sha256
from spade.metrics.shape_paths import render_paths, rotate_paths, sample_paths, straight_paths
from spade.metrics.synthetic import degrade, synthetic_batch

N = 300  # > 240 features + 1 (randconv); the default shape extractor has 64
SIZE = 32


@pytest.fixture(scope="module")
def real() -> torch.Tensor:
    return torch.from_numpy(synthetic_batch(N, size=SIZE, seed=1)["path"])


@pytest.fixture(scope="module")
def generated() -> np.ndarray:
    return synthetic_batch(N, size=SIZE, seed=2)["path"]


def scipy_reference(f_real: np.ndarray, f_fake: np.ndarray) -> float:
    """The textbook float64 computation (pytorch-fid's formula) with scipy's sqrtm of the product."""
    mu1, mu2 = f_real.mean(0), f_fake.mean(0)
    s1, s2 = np.cov(f_real, rowvar=False), np.cov(f_fake, rowvar=False)
    covmean = linalg.sqrtm(s1 @ s2)
    diff = mu1 - mu2
    return float(diff @ diff + np.trace(s1) + np.trace(s2) - 2 * np.trace(covmean.real))


def test_default_extractor_is_the_pinned_shape_features(tmp_path) -> None:
    fid = FID()
    assert fid.feature_dim == 64 and isinstance(fid.extractor, ShapeFeatures)
    assert fid.extractor.sha256 == DEFAULT_SHAPE_SHA256
    assert fid.identity == f"shape-v1_c1_D64_sha256-{DEFAULT_SHAPE_SHA256[:12]}"
    assert not list(fid.parameters()) and not fid.extractor.state_dict()  # buffers: no optimiser, no checkpoint
    with np.load(SHAPE_WEIGHTS_FILE) as data:
        arrays = {k: data[k] for k in data.files}
    assert weights_sha256(arrays) == DEFAULT_SHAPE_SHA256
    arrays["embed.bias"] = arrays["embed.bias"] + np.float32(1e-3)  # any change to the weights changes the hash
    altered = tmp_path / "altered.npz"
    np.savez(altered, **arrays)
    other = ShapeFeatures(altered)  # another file is not pinned unless asked ...
    assert other.identity != fid.identity
    with pytest.raises(RuntimeError, match="not the pinned"):  # ... and is refused against the pin
        ShapeFeatures(altered, expected_sha256=DEFAULT_SHAPE_SHA256)
    with pytest.raises(FileNotFoundError, match="train_shape_features"):
        ShapeFeatures(tmp_path / "missing.npz")


def test_randconv_extractor_is_pinned_and_named() -> None:
    fid = FID("randconv")
    assert fid.feature_dim == 240
    assert fid.extractor.sha256 == DEFAULT_RANDCONV_SHA256
    assert fid.identity == f"randconv-v2_c1_16-32-48_g1-1-2_seed0_sha256-{DEFAULT_RANDCONV_SHA256[:12]}"
    assert RandomConvFeatures(seed=1).identity != fid.identity
    assert not list(fid.parameters())  # weights are buffers: never trained, never in an optimiser
    with pytest.raises(RuntimeError, match="not the pinned"):
        RandomConvFeatures(seed=1, expected_sha256=DEFAULT_RANDCONV_SHA256)


def test_fid_of_a_set_with_itself_is_zero(real: torch.Tensor) -> None:
    fid = FID()
    fid.update(real, real=True)
    fid.update(real, real=False)
    value = fid.compute()["fid"].item()
    scale = float(np.trace(fid._gaussian("real")[1]))
    assert abs(value) < 1e-9 * scale


def test_agrees_with_float64_scipy_sqrtm_reference(real: torch.Tensor, generated: np.ndarray) -> None:
    fake = torch.from_numpy(degrade(generated, "blur", 1.0))
    fid = FID()
    fid.update(real, real=True)
    fid.update(fake, real=False)
    ours = fid.compute()["fid"].item()
    f_real = fid.extractor(real).double().numpy()
    f_fake = fid.extractor(fake).double().numpy()
    assert ours == pytest.approx(scipy_reference(f_real, f_fake), rel=1e-6)


def test_frechet_distance_of_known_gaussians() -> None:
    # Commuting covariances: Tr((S1 S2)^(1/2)) = sum sqrt(l1 l2).
    l1, l2 = np.array([1.0, 4.0, 9.0]), np.array([4.0, 1.0, 0.25])
    expected = 3.0 + np.sum(l1 + l2 - 2 * np.sqrt(l1 * l2))
    rot = linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]
    s1, s2 = rot @ np.diag(l1) @ rot.T, rot @ np.diag(l2) @ rot.T
    assert frechet_distance(np.zeros(3), s1, np.ones(3), s2) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("extractor, rel", [("randconv", 1e-9), ("shape", 1e-6)])
def test_independent_of_batch_split(real: torch.Tensor, generated: np.ndarray, extractor: str, rel: float) -> None:
    """The float64 states make the sums exact whatever the split; the shape network's float32 layers round a
    feature differently with the batch size (about 1e-8 relative), hence its looser tolerance."""
    fake = torch.from_numpy(generated)
    whole = FID(extractor)
    whole.update(real, real=True)
    whole.update(fake, real=False)
    pieces = FID(extractor)
    for start in range(0, N, 37):
        pieces.update(fake[start : start + 37], real=False)
        pieces.update(real[start : start + 37], real=True)
    assert pieces.compute()["fid"].item() == pytest.approx(whole.compute()["fid"].item(), rel=rel)


@pytest.mark.parametrize(
    "kind, levels",
    [("shift", [0, 2, 6]), ("blur", [0, 0.7, 1.5]), ("dropout", [0, 0.2, 0.5]), ("blobs", [0, 2, 6])],
)
def test_randconv_rises_monotonically_with_drawing_degradation(real: torch.Tensor, generated: np.ndarray, kind: str,
                                                                levels: list) -> None:
    fid = FID("randconv", reset_real_features=False)
    fid.update(real, real=True)
    values = []
    for level in levels:
        fid.reset()
        fid.update(torch.from_numpy(degrade(generated, kind, level, seed=3)), real=False)
        values.append(fid.compute()["fid"].item())
    assert all(b > a for a, b in zip(values, values[1:])), f"FID not increasing for {kind}: {values}"


def test_any_image_size_and_channel_count() -> None:
    ext = RandomConvFeatures(in_channels=4)
    for hw in ((16, 16), (24, 40), (128, 128)):
        assert ext(torch.rand(2, 4, *hw)).shape == (2, ext.feature_dim)
    with pytest.raises(ValueError, match=r"\(B, 4, H, W\)"):
        ext(torch.rand(2, 1, 16, 16))
    shape = build_feature_extractor("shape")
    for hw in ((32, 32), (24, 40), (64, 64), (128, 128), (256, 256)):
        assert shape(torch.rand(2, 1, *hw)).shape == (2, 64)
    with pytest.raises(ValueError, match=r"\(B, 1, H, W\)"):
        shape(torch.rand(2, 3, 64, 64))
    with pytest.raises(ValueError, match="one-channel"):
        build_feature_extractor("shape", in_channels=3)


def test_too_few_samples_names_the_needed_number(real: torch.Tensor) -> None:
    fid = FID()
    fid.update(real[:30], real=True)
    fid.update(real[:300], real=False)
    with pytest.raises(ValueError, match="needs at least 65 real and 65 generated images .*; got 30 real and 300"):
        fid.compute()
    fid = FID("randconv")
    fid.update(real[:100], real=True)
    fid.update(real[:300], real=False)
    with pytest.raises(ValueError, match="needs at least 241 real and 241 generated images .*; got 100 real and 300"):
        fid.compute()


def test_inception_option_fails_clearly_without_weights(tmp_path) -> None:
    with pytest.raises(ValueError, match="inception.*inception_v3_google-0cc3c7bd.pth.*download"):
        FID("inception")
    with pytest.raises(FileNotFoundError, match="inception.*not found.*download.pytorch.org"):
        FID("inception", extractor_kwargs={"weights_path": tmp_path / "missing.pth"})
    weights = tmp_path / "inception_v3_google-0cc3c7bd.pth"
    weights.write_bytes(b"not really weights")
    try:
        import torchvision  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="'inception' needs torchvision"):
            FID("inception", extractor_kwargs={"weights_path": weights})
    else:  # torchvision present: the bogus file must be rejected when loading
        with pytest.raises(Exception):
            FID("inception", extractor_kwargs={"weights_path": weights})
    with pytest.raises(ValueError, match="unknown FID feature extractor"):
        build_feature_extractor("vgg")


def test_custom_extractor_needs_identity() -> None:
    with pytest.raises(TypeError, match="'feature_dim'"):
        FID(torch.nn.Flatten())


# --- The default extractor sees path shape ------------------------------------------------------------------------
# Robot-frame remaining paths of L templates (spade.metrics.shape_paths: the annotation tool's ranges, robot at
# (W/2, 3W/4) heading up, drawn like a dataset's path channel). The reference set and the disjoint ground-truth
# sample use different seeds; every changed set is the disjoint sample with one change (same seed).

SHAPE_N = 300
SHAPE_LEVELS = {"shift_px": [0, 2, 4, 8], "gap": [0, 0.1, 0.2, 0.35], "radius_scale": [1.0, 0.6, 0.3, 0.0]}


class _Against:
    """FID of sets against one real set, its statistics accumulated once."""

    def __init__(self, real: np.ndarray, extractor: str | torch.nn.Module = "shape") -> None:
        self.fid = FID(extractor, reset_real_features=False)
        self.fid.update(torch.from_numpy(real), real=True)

    def __call__(self, fake: np.ndarray) -> float:
        self.fid.reset()
        self.fid.update(torch.from_numpy(fake), real=False)
        return self.fid.compute()["fid"].item()


def shape_changes(gen: list) -> dict[str, tuple[np.ndarray, float]]:
    """The L paths ``gen`` changed in shape, drawn at 64 px, each with the margin over the ground truth's FID that
    the shape extractor must keep."""
    return {
        "straight lines": (render_paths(straight_paths(gen), 64), 30.0),
        "U instead of L": (render_paths(sample_paths(SHAPE_N, "U", 64, 0.1, seed=2), 64), 30.0),
        "sharp corners (radius 0)": (render_paths(sample_paths(SHAPE_N, "L", 64, 0.1, seed=2, radius_scale=0.0), 64),
                                     5.0),
        "middle third removed": (render_paths(gen, 64, gap=1 / 3), 5.0),
        "rotated 180 degrees": (render_paths(rotate_paths(gen, 64), 64), 30.0),
    }


@pytest.fixture(scope="module")
def l_paths() -> dict:
    size = 64
    gen = sample_paths(SHAPE_N, "L", size, 0.1, seed=2)
    return {"real": render_paths(sample_paths(SHAPE_N, "L", size, 0.1, seed=1), size), "gen": gen,
            "gt": render_paths(gen, size)}


@pytest.fixture(scope="module")
def shape_fid(l_paths: dict) -> _Against:
    return _Against(l_paths["real"])


@pytest.fixture(scope="module")
def gt_fid(l_paths: dict, shape_fid: _Against) -> float:
    return shape_fid(l_paths["gt"])


def test_ground_truth_resample_is_smallest_and_shape_changes_score_far_higher(l_paths: dict, shape_fid: _Against,
                                                                            gt_fid: float) -> None:
    """Measured (shape-v1, 300 vs 300 at 64 px): ground truth vs a disjoint sample ~0.3; the changed sets 20x to
    300x that. Stated margins: at least MARGIN x the ground-truth value, and above an absolute floor."""
    gen = l_paths["gen"]
    changed = shape_changes(gen)
    assert 0 < gt_fid < 1.0, gt_fid
    values = {name: shape_fid(images) for name, (images, _) in changed.items()}
    for name, (_, margin) in changed.items():
        assert values[name] > margin * gt_fid and values[name] > 2.0, (name, values[name], gt_fid)


@pytest.mark.parametrize("kind", sorted(SHAPE_LEVELS))
def test_rises_monotonically_with_growing_shape_corruption(l_paths: dict, shape_fid: _Against, gt_fid: float,
                                                          kind: str) -> None:
    levels = SHAPE_LEVELS[kind]
    values = [gt_fid]
    for level in levels[1:]:
        if kind == "shift_px":
            images = render_paths(l_paths["gen"], 64, shift_px=level, seed=3)
        elif kind == "gap":
            images = render_paths(l_paths["gen"], 64, gap=level)
        else:
            images = render_paths(sample_paths(SHAPE_N, "L", 64, 0.1, seed=2, radius_scale=level), 64)
        values.append(shape_fid(images))
    assert all(b > a for a, b in zip(values, values[1:])), f"FID not increasing with {kind} {levels}: {values}"
    assert values[-1] > 5 * values[0], values


def test_same_paths_at_128_px_look_alike(l_paths: dict, shape_fid: _Against, gt_fid: float) -> None:
    """A 128 px window at 0.05 m/px covers the 64 px window's 6.4 m: the same distribution of paths drawn at 128 px
    scores close to the 64 px ground truth and far below straight lines drawn at 128 px."""
    paths = sample_paths(200, "L", 128, 0.05, seed=2)
    near = shape_fid(render_paths(paths, 128))
    far = shape_fid(render_paths(straight_paths(paths), 128))
    assert near < 10 * gt_fid and far > 10 * near, (gt_fid, near, far)


@pytest.mark.slow
@pytest.mark.parametrize("size", [64, 128])
def test_shape_validity_at_scale(size: int) -> None:
    """The validity checks with 1,000 paths per set, at 64 and 128 px, the reference FID too."""
    from spade.perf.metrics import shape_validity

    result = shape_validity(1000, size, seed=5, extractors=("shape",))
    (row,) = result["rows"]
    fids = {s["set"]: s["fid"] for s in row["sets"]}
    base = fids.pop("ground truth (disjoint sample)")
    assert all(v > 5 * base for v in fids.values()), (base, fids)
    assert all(g["monotonic"] for g in row["growing"]), row["growing"]


@pytest.mark.slow
def test_rebuild_command_reproduces_the_pinned_weights(tmp_path, l_paths: dict) -> None:
    """python -m spade.metrics.train_shape_features rebuilds the shipped weights: bit for bit on the CPU kind and
    torch build that pinned them (about 2-6 minutes on one core, data generation included).

    Elsewhere rounding differs (CI's machine gave another hash) and 14 epochs of training amplify it as far as a
    new seed would: there the rebuilt extractor must be the same instrument, not the same bytes. Its FIDs of the
    probe sets lie within the spread of a seed change (measured: seed 1 against the shipped seed 0 moved them by
    1-22 %; allowed: a factor 1.6) and keep every margin the shipped extractor's validity tests state."""
    import json
    import warnings

    from spade.metrics.train_shape_features import main

    out = tmp_path / "w.npz"
    summary = main([f"data_dir={tmp_path / 'data'}", f"out={out}"])
    if summary["sha256"] == DEFAULT_SHAPE_SHA256:
        return
    warnings.warn(f"the rebuilt shape weights hash to {summary['sha256'][:12]}, not the pinned "
                  f"{DEFAULT_SHAPE_SHA256[:12]}: this machine ({json.dumps(summary['platform'])}) rounds otherwise "
                  f"than the one that pinned them; checked as an equivalent extractor instead")
    assert summary["history"][-1]["held_kind_accuracy"] >= 0.95, summary["history"][-1]
    gen = l_paths["gen"]
    probes = {"ground truth": render_paths(gen, 64), **{n: im for n, (im, _) in shape_changes(gen).items()}}
    shipped, rebuilt = _Against(l_paths["real"]), _Against(l_paths["real"], ShapeFeatures(out))
    for name, images in probes.items():
        a, b = shipped(images), rebuilt(images)
        assert a / 1.6 < b < a * 1.6, (name, a, b)
        if name == "ground truth":
            gt = b
            assert 0 < gt < 1.0, gt
        else:
            assert b > 5 * gt and b > 2.0, (name, b, gt)


def test_training_targets_read_the_shape() -> None:
    """The descriptor the extractor is trained to predict: kind and total turn of straight, L and U paths, the
    turn's direction, the missing fraction."""
    from spade.metrics.train_shape_features import descriptor

    from spade.metrics.shape_paths import template_curve, to_robot_frame

    l_left = to_robot_frame(template_curve(15, 5, 10, 90, left=True, step=0.5), 64)
    u_right = to_robot_frame(template_curve(20, 4, 12, 180, left=False, step=0.5), 64)
    # total turn / pi, in image coordinates (rows down): a left turn is negative
    for pts, kind, turn in ((np.array([[32.0, 48.0], [32.0, 10.0]]), 0, 0.0), (l_left, 1, -0.5), (u_right, 2, 1.0)):
        t, k = descriptor(pts, 64)
        assert k == kind and abs(t[-2] - turn) < 0.05, (k, t[-2])
    t = descriptor(l_left, 64)[0]
    mirrored = np.stack([64.0 - l_left[:, 0], l_left[:, 1]], axis=1)  # left-right mirror about the robot
    assert descriptor(mirrored, 64)[0][-2] == pytest.approx(-t[-2], abs=1e-6)
    assert descriptor(l_left * 2 + 0.5, 128)[0] == pytest.approx(t, abs=1e-5)  # the same path at 128 px
    assert descriptor(l_left, 64, gap=0.3)[0][-1] == pytest.approx(0.3)


def test_training_is_deterministic_from_its_seed() -> None:
    """Two short trainings from one seed give the same weights (hence the same sha256): what makes the rebuild
    command reproduce the pin."""
    from spade.metrics.shape_features import weights_sha256
    from spade.metrics.train_shape_features import descriptor, train

    paths = sample_paths(48, "L", 64, 0.1, seed=4) + sample_paths(16, "U", 64, 0.1, seed=4)
    targets, kinds = zip(*(descriptor(p, 64) for p in paths))
    samples = {"images": render_paths(paths, 64)[:, 0].astype(np.uint8), "targets": np.stack(targets),
               "kinds": np.array(kinds), "held": np.arange(64) % 8 == 0}
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as the rebuild command does
    try:
        hashes = [weights_sha256(train(samples, epochs=1, seed=3, batch=16, lr=1e-3, log=lambda _: None)[0]
                                 .feature_arrays()) for _ in range(2)]
    finally:
        torch.set_num_threads(threads)
    assert hashes[0] == hashes[1]


def test_a_garbage_weights_file_is_named_without_numpys_pickle_hint(tmp_path) -> None:
    """A garbage FID feature file got numpy's "load it unsafely using allow_pickle" hint."""
    from spade.metrics.shape_features import ShapeFeatures

    garbage = tmp_path / "features.npz"
    garbage.write_bytes(b"not an npz" * 50)
    with pytest.raises(ValueError, match="is not a weights file") as info:
        ShapeFeatures(weights_path=garbage)
    assert "allow_pickle" not in str(info.value)


def _symmetric_reference(f_real: np.ndarray, f_fake: np.ndarray) -> float:
    """The float64 formula SPADE computed before it used torchmetrics': Tr((S_r S_g)^(1/2)) from the eigenvalues of
    the symmetric sqrt(S_r) S_g sqrt(S_r), two symmetric eigendecompositions."""
    mu_r, mu_g = f_real.mean(0), f_fake.mean(0)
    s_r, s_g = np.cov(f_real, rowvar=False), np.cov(f_fake, rowvar=False)
    w, v = linalg.eigh(s_r)
    root = (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T
    m = root @ s_g @ root
    tr_covmean = np.sqrt(np.clip(linalg.eigvalsh((m + m.T) / 2.0), 0.0, None)).sum()
    diff = mu_r - mu_g
    return float(diff @ diff + np.trace(s_r) + np.trace(s_g) - 2.0 * tr_covmean)


@pytest.mark.parametrize("extractor", ["shape", "randconv"])
@pytest.mark.parametrize("kind, level", [("blur", 1.0), ("shift", 6), ("dropout", 0.5), ("none", 0)])
def test_torchmetrics_fid_matches_the_symmetric_float64_formula(real: torch.Tensor, generated: np.ndarray,
                                                                extractor: str, kind: str, level: float) -> None:
    """FID is torchmetrics' FrechetInceptionDistance with SPADE's extractor: its figures are the ones SPADE's own
    symmetric float64 computation gave, within 1e-8 of the covariance's trace (measured: at most 2e-9)."""
    fake = torch.from_numpy(generated if kind == "none" else degrade(generated, kind, level, seed=3))
    fid = FID(extractor)
    fid.update(real, real=True)
    fid.update(fake, real=False)
    ours = fid.compute()["fid"].item()
    f_real = fid.extractor(real).double().numpy()
    f_fake = fid.extractor(fake).double().numpy()
    scale = float(np.trace(np.cov(f_real, rowvar=False)))
    assert abs(ours - _symmetric_reference(f_real, f_fake)) < 1e-8 * scale
