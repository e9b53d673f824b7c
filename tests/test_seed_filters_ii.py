"""UKF, DE and the adaptive GA: the papers' formulas by hand, UKF = Kalman on a linear model, properties."""
import math

import numpy as np
import pytest

from aoa_localizer import LocalizerConfig
from aoa_localizer.filters import make_filter
from aoa_localizer.filters.agapf import adaptive_pc, adaptive_pm
from aoa_localizer.filters.de import crossover, distinct_indices, evolve, mutate
from aoa_localizer.filters.ukf import BatchedUKF, gauss_logpdf
from aoa_localizer.models import benchmarks as B
from aoa_localizer.simulation.evaluation import run_model


def test_batched_ukf_equals_the_kalman_filter_on_a_linear_model():
    rng = np.random.default_rng(0)
    A = np.array([[1.0, 1.0], [0.0, 1.0]])
    Q = np.diag([0.1, 0.05])
    H = np.array([[1.0, 0.5]])
    R = np.array([[0.3]])
    m = rng.normal(size=(3, 2))
    P = np.stack([np.eye(2) * s for s in (0.5, 1.0, 2.0)])
    z = np.array([0.7])
    ukf = BatchedUKF(2)
    mu, Pu = ukf.predict(m, P, lambda X: X @ A.T, Q)
    mu, Pu = ukf.update(mu, Pu, lambda X: X @ H.T, R, z)
    for i in range(3):
        mp, Pp = A @ m[i], A @ P[i] @ A.T + Q
        S = H @ Pp @ H.T + R
        K = Pp @ H.T @ np.linalg.inv(S)
        assert mu[i] == pytest.approx(mp + K @ (z - H @ mp))
        assert Pu[i] == pytest.approx(Pp - K @ S @ K.T)


def test_ukf_wraps_angle_innovations():
    ukf = BatchedUKF(2)
    m = np.array([[-1000.0, 1.0]])  # due west of the origin: bearing near +pi
    P = np.eye(2)[None] * 4.0
    h = lambda X: np.arctan2(X[..., 1], X[..., 0])[..., None]  # noqa: E731
    mu, _ = ukf.update(m, P, h, np.array([[1e-4]]), np.array([-math.pi + 0.001]), [True])
    assert abs(mu[0, 1] - 1.0) < 3.0  # a 2 pi jump would fling the mean kilometres away
    assert np.all(np.isfinite(mu))


def test_gauss_logpdf_by_hand():
    x = np.array([[1.0, 2.0]])
    assert gauss_logpdf(x, np.zeros((1, 2)), np.eye(2)[None])[0] == pytest.approx(-2.5 - math.log(2 * math.pi))


def test_de_operators_for_fixed_draws():
    idx = distinct_indices(6, np.random.default_rng(1))
    for i, row in enumerate(idx):
        assert len({i, *row.tolist()}) == 4
    x = np.array([[0.0, 0.0], [1.0, 2.0], [3.0, 5.0], [4.0, 4.0]])
    v = mutate(x, np.array([[1, 2, 3], [0, 2, 3], [3, 0, 1], [0, 1, 2]]), 1.0, 0.9)
    assert v[0] == pytest.approx([1.0 + 0.9 * (3 - 4), 2.0 + 0.9 * (5 - 4)])
    u = np.array([[0.1, 0.9], [0.9, 0.9], [0.7, 0.2], [0.9, 0.9]])
    trial = crossover(x, v, 0.6, u, np.array([1, 0, 0, 1]))
    assert trial[0].tolist() == v[0].tolist()  # both: u <= Cr, and dimension 1 forced
    assert trial[1].tolist() == [v[1, 0], x[1, 1]]  # only the forced dimension
    assert trial[2].tolist() == [v[2, 0], v[2, 1]]  # forced 0, u = 0.2 <= Cr
    assert trial[3].tolist() == [x[3, 0], v[3, 1]]


def test_greedy_selection_never_lowers_fitness():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(20, 2))
    score = lambda p: -np.sum(p**2, axis=1)  # noqa: E731
    cfg = LocalizerConfig().de
    x2, f2 = evolve(x, score(x), score, cfg, rng)
    assert np.all(f2 >= score(x)) and np.allclose(f2, score(x2)) and f2.max() > score(x).max()


def test_adaptive_probabilities_at_their_ends_and_at_the_average():
    g = LocalizerConfig().agapf
    # As printed (a jump to the mid value at the average):
    assert adaptive_pc(0.1, 0.2, 0.5, g.pc1, g.pc2, g.a, "printed") == pytest.approx(g.pc1)
    assert adaptive_pc(0.2, 0.2, 0.5, g.pc1, g.pc2, g.a, "printed") == pytest.approx((g.pc1 + g.pc2) / 2)
    assert adaptive_pc(0.5, 0.2, 0.5, g.pc1, g.pc2, g.a, "printed") == pytest.approx(g.pc2, abs=1e-6)
    assert adaptive_pm(0.2, 0.2, 0.5, g.pm1, g.pm2, g.a, "printed") == pytest.approx((g.pm1 + g.pm2) / 2)
    # Kuang et al.'s sigmoid with its "- 1" (the default): continuous at the average, pc2/pm2 at the best.
    # At f_avg: p1 - (p1 - p2) / (1 + e^A) = 0.95 - 0.45 / (1 + e^9.9034) = 0.949978...
    assert g.curve == "kuang"
    assert adaptive_pc(0.2, 0.2, 0.5, g.pc1, g.pc2, g.a) == pytest.approx(0.95 - 0.45 / (1 + math.exp(9.9034)))
    assert adaptive_pc(0.1999, 0.2, 0.5, g.pc1, g.pc2, g.a) == pytest.approx(g.pc1)
    assert adaptive_pc(0.5, 0.2, 0.5, g.pc1, g.pc2, g.a) == pytest.approx(0.5 + 0.45 / (1 + math.exp(9.9034)))
    assert adaptive_pc(0.35, 0.2, 0.5, g.pc1, g.pc2, g.a) == pytest.approx((g.pc1 + g.pc2) / 2)  # mid-way
    assert adaptive_pm(0.5, 0.2, 0.5, g.pm1, g.pm2, g.a) == pytest.approx(g.pm2, abs=1e-5)  # the fittest mutate least
    assert adaptive_pm(0.2, 0.2, 0.5, g.pm1, g.pm2, g.a) == pytest.approx(g.pm1, abs=1e-5)


@pytest.mark.parametrize("algorithm", ["upfde", "upf", "pfde", "agapf"])
def test_weights_finite_and_normalised_and_runs_reproducible(algorithm):
    model = B.upfde_model()
    cfg = LocalizerConfig(algorithm=algorithm, num_particles=10, seed=1).with_changes(
        **{"upf.variant": "paper", "de.variant": "paper", "agapf.variant": "paper"})
    f = make_filter(cfg, np.random.default_rng(1), model)
    f.initialise(model.initial(10, np.random.default_rng(2)))
    _, zs = model.simulate(40, np.random.default_rng(3))
    for z in zs:
        f.update(z)
        assert np.all(np.isfinite(f.x)) and f.weights.sum() == pytest.approx(1.0) and np.all(np.isfinite(f.weights))
    a = run_model(model, algorithm, 10, 40, 4, 5)
    b = run_model(model, algorithm, 10, 40, 4, 5)
    assert np.array_equal(a[1], b[1])


def _rmse(model, algorithm, n, steps, runs, **changes):
    per_run = [np.sqrt(np.mean((t - e) ** 2)) for t, e, _ in
               (run_model(model, algorithm, n, steps, r, 1000 + r, **changes) for r in range(runs))]
    return float(np.mean(per_run))


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["upfde", "upf", "pfde"])
def test_the_unscented_and_de_filters_beat_the_bootstrap_filter_on_their_papers_model(algorithm):
    model = B.upfde_model()
    assert _rmse(model, algorithm, 10, 50, 10) < 0.5 * _rmse(model, "sir", 10, 50, 10, ess_threshold=1.0)


def test_aga_pf_offspring_carry_equal_weights_the_newest_likelihood_counted_once():
    """AGA-PF's round-1 bug: selection by the likelihood, then the offspring weighted by it again."""
    model = B.upfde_model()
    cfg = LocalizerConfig(algorithm="agapf", num_particles=50, seed=2).with_changes(**{"agapf.variant": "paper"})
    f = make_filter(cfg, np.random.default_rng(2), model)
    f.initialise(model.initial(50, np.random.default_rng(3)))
    _, zs = model.simulate(5, np.random.default_rng(4))
    for z in zs:
        assert f.update(z)
        assert np.all(f.logw == 0.0)  # the estimate is the plain mean of the selected, crossed, mutated population
