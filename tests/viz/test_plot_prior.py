"""``driveopt plot-prior`` (P2 Fig. 1): one column per prior with trajectories and set-point densities; the KDE."""

from __future__ import annotations

import matplotlib.image
import numpy as np
import pytest
from tiny_models import tiny_cvae, tiny_pixelcnn

from driveopt.cli import main
from driveopt.scene import builtin_problems, load_scene
from driveopt.viz.kde import KDEError, gaussian_kde, scott_bandwidth
from driveopt.viz.plan_plot import plt
from driveopt.viz.prior_plot import COLUMN_WIDTH, ROWS

DPI = 110  # driveopt.viz.plan_plot.save_figure


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny")
    return tiny_cvae(root / "cvae.ckpt"), tiny_pixelcnn(root / "pixelcnn.ckpt")


def _columns(png) -> float:
    """How many prior columns a written figure is wide."""
    return matplotlib.image.imread(png).shape[1] / (COLUMN_WIDTH * DPI)


def test_kde_matches_a_hand_computed_density_and_integrates_to_one():
    grid = np.array([0.0, 1.0, 3.0])
    # two samples at 0 and 2, bandwidth 1: (N(x; 0, 1) + N(x; 2, 1)) / 2
    phi = lambda z: np.exp(-0.5 * z**2) / np.sqrt(2 * np.pi)  # noqa: E731
    np.testing.assert_allclose(gaussian_kde([0.0, 2.0], grid, bandwidth=1.0), [(phi(0) + phi(2)) / 2, phi(1), (phi(3) + phi(1)) / 2])
    samples = np.random.default_rng(0).normal(5.0, 2.0, 500)
    assert scott_bandwidth(samples, 0.05) == pytest.approx(np.std(samples, ddof=1) * 500 ** -0.2)
    fine = np.linspace(-10, 20, 3001)
    assert np.trapezoid(gaussian_kde(samples, fine), fine) == pytest.approx(1.0, abs=1e-3)
    collapsed = gaussian_kde(np.full(100, 4.0), fine)  # every sample in one lane: a peak of width min_bandwidth
    assert fine[np.argmax(collapsed)] == pytest.approx(4.0) and np.trapezoid(collapsed, fine) == pytest.approx(1.0, abs=1e-3)
    for bad in ([], [1.0, np.nan]):
        with pytest.raises(KDEError):
            gaussian_kde(bad, fine)
    with pytest.raises(KDEError, match="bandwidth"):
        gaussian_kde([1.0], fine, bandwidth=0.0)


def test_the_multi_homotopy_problems_are_built_in():
    assert {"slow-leader-three-lane", "slow-leader-four-lane"} <= set(builtin_problems())
    for name, lanes in (("slow-leader-three-lane", 3), ("slow-leader-four-lane", 4)):
        scene = load_scene(name)
        assert scene.road.num_lanes == lanes and scene.ego.y == 4.0  # lane 1: a lane on either side
        ahead = [n for n in scene.neighbours if n.y == scene.ego.y]
        assert len(ahead) == 1 and ahead[0].x > scene.ego.x and ahead[0].vx < scene.ego.vx  # a slow car ahead
        assert not [n for n in scene.neighbours if n.y in (0.0, 8.0)]  # both neighbouring lanes open


def test_plot_prior_draws_one_column_per_prior_with_densities(weights, tmp_path, capsys, monkeypatch):
    cvae_path, pixelcnn_path = weights
    out = tmp_path / "prior.png"
    args = ["plot-prior", "--problem", "slow-leader-four-lane", "--samples", "40", "--out", str(out)]
    assert main([*args, "--cvae-weights", str(cvae_path), "--vqvae-weights", str(pixelcnn_path)]) == 0
    printed = capsys.readouterr()
    assert f"wrote {out}: 4 priors" in printed.out and "CVAE (cvae.ckpt)" in printed.out
    assert "VQ-VAE + PixelCNN (pixelcnn.ckpt)" in printed.out and printed.err == ""
    assert _columns(out) == pytest.approx(4, abs=0.05)
    # A road without shipped VQ-VAE weights: a notice, and the column left out.
    monkeypatch.setattr("driveopt.priors.vqvae.SHIPPED", {})
    assert main([*args, "--cvae-weights", str(cvae_path)]) == 0
    printed = capsys.readouterr()
    assert "3 priors" in printed.out and "VQ-VAE" not in printed.out
    assert "VQ-VAE + PixelCNN: no weights shipped for 4-lane roads (pass --vqvae-weights FILE): column left out" in printed.err
    assert _columns(out) == pytest.approx(3, abs=0.05)


def test_plot_priors_returns_its_panels(weights, tmp_path):
    from driveopt.config import PlannerConfig
    from driveopt.priors.vqvae import load_prior
    from driveopt.sampler import GaussianPrior
    from driveopt.viz.prior_plot import plot_priors

    config = PlannerConfig()
    priors = {"Gaussian": GaussianPrior(), "VQ-VAE": load_prior(weights[1])}
    figure = plot_priors(priors, load_scene("slow-leader-four-lane"), config, tmp_path / "p.png", num=30, notes=["a note"])
    assert figure.columns == ("Gaussian", "VQ-VAE") and figure.panels == 2 * len(ROWS)
    assert figure.path.stat().st_size > 10_000 and plt.get_fignums() == []  # written and closed


@pytest.mark.parametrize("which", ["--vqvae-weights", "--cvae-weights"])
@pytest.mark.parametrize("damage", ["missing", "corrupt", "other-lanes"])
def test_unusable_weights_are_one_line_errors(weights, tmp_path, capsys, which, damage):
    good = weights[1] if which == "--vqvae-weights" else weights[0]
    path = tmp_path / "bad.ckpt"
    if damage == "corrupt":
        raw = good.read_bytes()
        path.write_bytes(raw[: len(raw) // 2])
    elif damage == "other-lanes":
        (tiny_pixelcnn if which == "--vqvae-weights" else tiny_cvae)(path, lanes=(2,))
    out = tmp_path / "prior.png"
    assert main(["plot-prior", "--problem", "slow-leader-four-lane", "--samples", "10", which, str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("driveopt: error: ") and err.count("\n") == 1 and str(path) in err
    assert {"missing": "no such file", "corrupt": "corrupted", "other-lanes": "2-lane roads, not this 4-lane road"}[damage] in err
    assert not out.exists()
