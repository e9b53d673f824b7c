"""ESPF and GFA-PF: the papers' formulas by hand, their properties, and the benchmark models."""
import math

import numpy as np
import pytest

from aoa_localizer import LocalizerConfig
from aoa_localizer.filters import make_filter
from aoa_localizer.filters.espf import sbx_beta, sbx_children, top_n
from aoa_localizer.filters.gfapf import gravitation_step
from aoa_localizer.models import benchmarks as B
from aoa_localizer.simulation.evaluation import run, run_model
from aoa_localizer.simulation.scenarios import simulate


def test_sbx_children_by_hand():
    # lambda = 1: u = 0.25 -> beta = sqrt(0.5); u = 0.75 -> beta = sqrt(2).
    beta = sbx_beta(np.array([0.25, 0.75, 0.5]), 1.0)
    assert beta == pytest.approx([math.sqrt(0.5), math.sqrt(2.0), 1.0])
    c1, c2 = sbx_children(np.array([[1.0], [1.0], [1.0]]), np.array([[3.0], [3.0], [3.0]]), beta)
    assert c1[:, 0] == pytest.approx([1.292893, 0.585786, 1.0], abs=1e-6)
    assert c2[:, 0] == pytest.approx([2.707107, 3.414214, 3.0], abs=1e-6)
    assert (c1 + c2)[:, 0] == pytest.approx([4.0, 4.0, 4.0])  # children keep the parents' mean


def test_larger_sbx_lambda_keeps_children_nearer_their_parents():
    u = np.random.default_rng(0).random(10000)
    spread = [np.mean(np.abs(sbx_beta(u, lam) - 1.0)) for lam in (0.0, 2.0, 10.0, 50.0)]
    assert spread == sorted(spread, reverse=True)


def test_selection_keeps_exactly_n_and_the_best():
    w = np.array([0.1, 0.5, 0.2, 0.4, 0.5])
    assert top_n(w, 3).tolist() == [1, 4, 3]


def test_gravitation_step_at_its_thresholds_by_hand():
    x = np.array([[0.0], [0.1], [0.2], [0.3], [0.5], [1.0]])  # the centre dust is x[0]
    f = np.full(6, 0.3)
    new = gravitation_step(x, 0, 1.0, 0.0618, 0.5, 0.2, f)
    assert new[0, 0] == 0.0
    assert new[1, 0] == pytest.approx(0.1 + 0.3 * 0.1 ** (1 / 3))  # repelled, not attracted
    assert new[2, 0] == pytest.approx(0.2 + 0.3 * 0.2 ** (1 / 3))  # |dis| = 0.2: repulsion still on
    assert new[3, 0] == pytest.approx(0.3)  # dead zone of both
    assert new[4, 0] == pytest.approx(0.5 - 0.0618 * 0.5)  # |dis| = 0.5: attraction on
    assert new[5, 0] == pytest.approx(1.0 - 0.0618)


def test_gravitation_scales_with_the_problem_in_spread_units():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(50, 2))
    f = rng.random(50) * 0.3
    small = gravitation_step(x, 3, 0.4, 0.0618, 0.5, 0.2, f)
    large = gravitation_step(1000 * x, 3, 400.0, 0.0618, 0.5, 0.2, f)
    assert large == pytest.approx(1000 * small)


@pytest.mark.parametrize("algorithm", ["espf", "gfapf"])
def test_weights_stay_normalised_and_a_seed_reproduces_a_run(algorithm):
    model = B.espf_model2()
    cfg = LocalizerConfig.from_dict({"algorithm": algorithm, "num_particles": 64, "seed": 3, "gfapf.scale": "absolute",
                                     "espf.variant": "paper", "gfapf.variant": "paper"})
    f = make_filter(cfg, np.random.default_rng(3), model)
    f.initialise(model.initial(64, np.random.default_rng(4)))
    _, zs = model.simulate(20, np.random.default_rng(5))
    for z in zs:
        assert f.update(z)
        assert f.x.shape == (64, 1) and f.weights.sum() == pytest.approx(1.0) and np.all(f.weights >= 0)
    a = run_model(model, algorithm, 64, 20, 1, 2, **{"gfapf.scale": "absolute"})
    b = run_model(model, algorithm, 64, 20, 1, 2, **{"gfapf.scale": "absolute"})
    assert np.array_equal(a[1], b[1])


def test_espf_beats_the_bootstrap_filter_on_its_papers_model_1():
    model = B.espf_model1()

    def rmse(algorithm, **changes):
        sq = [(lambda t, e, _: (t - e) ** 2)(*run_model(model, algorithm, 200, 60, r, 1000 + r, **changes))
              for r in range(8)]
        return float(np.sqrt(np.mean(sq, axis=0)).mean())

    assert rmse("espf") < 0.85 * rmse("sir", ess_threshold=1.0)


def test_benchmark_models_by_hand():
    rng = np.random.default_rng(0)
    ungm = B.GrowthModel(a=0.5, b=25.0, c=8.0, kappa=20.0, q=0.0)
    assert ungm.transition(np.array([[1.0]]), 1, rng)[0, 0] == pytest.approx(0.5 + 12.5 + 8.0)  # cos(1.2 * 0) = 1
    assert ungm.loglik(np.array([[2.0]]), 0.2, 1)[0] == pytest.approx(-0.5 * math.log(2 * math.pi))
    gs = B.gfapf_model1(0.1)
    assert gs.h(2.0, 30) == pytest.approx(0.8) and gs.h(2.0, 31) == pytest.approx(-1.0)
    draws = B.GammaSineModel(shape=3.0, rate=2.0, phi=0.0, omega=0.0).transition(np.zeros((20000, 1)), 1, rng)
    assert draws.mean() == pytest.approx(1.0 + 1.5, abs=0.03)  # 1 + Gamma mean shape/rate
    ct = B.CoordinatedTurnModel(q=(0.0, 0.0))
    assert ct.h(np.array([3.0, 0.0, 4.0, 0.0])) == pytest.approx([5.0, math.atan2(4.0, 3.0)])
    moved = ct.transition(np.array([[7.0, 0.08, 6.0, 0.05]]), 1, rng)[0]
    assert moved == pytest.approx([7.08, 0.08, 6.05, 0.05], abs=2e-4)  # a slow turn: nearly straight for 1 s
    xs, zs = B.gfapf_ungm().simulate(30, np.random.default_rng(1), jump=(25, 10.0))
    assert xs.shape == (31, 1) and len(zs) == 30


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["espf", "gfapf"])
def test_seed_filters_localise_the_emitter_too(algorithm):
    s = run(simulate("seed", 0), LocalizerConfig(algorithm=algorithm, seed=10000)).scores
    assert s["converged"] and s["error"] < 100.0


def test_drawing_from_the_pool_gives_equal_weights_equal_shares_wherever_they_sit():
    """ESPF's round-1 bug: the N largest of the 2N pool, ties broken by position, culled the tail of the resampled
    block (all at 1/N) at every step. Drawn by weight, the head and the tail of the block fare the same."""
    from aoa_localizer.filters.resampling import systematic

    n = 200
    rng = np.random.default_rng(0)
    children = rng.random(n) ** 4
    pool = np.concatenate([np.full(n, 1.0 / n), children / children.sum()])
    kept = systematic(pool / pool.sum(), rng, n)
    head, tail = np.sum(kept < n // 2), np.sum((kept >= n // 2) & (kept < n))
    assert abs(int(head) - int(tail)) <= 1 and head + tail == pytest.approx(n / 2, abs=2)
    top = top_n(pool, n)
    assert np.sum(top < n // 2) > np.sum((top >= n // 2) & (top < n)) + 20  # the old selection's bias
