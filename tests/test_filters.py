import math

import numpy as np
import pytest

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.emitter_model import EmitterModel
from aoa_localizer.engine.inference.likelihood import (
    BearingLikelihood,
    gaussian_loglik_var,
    mixture_loglik,
)
from aoa_localizer.engine.scheduling import slices
from aoa_localizer.engine.scheduling.scheduler import SWEEP_PART, Scheduler
from aoa_localizer.engine.types import ObservationPoint
from aoa_localizer.filters import REGISTRY, make_filter
from aoa_localizer.filters.afsa import AfsaMoves, uniform_disc


def test_gaussian_loglik_by_hand():
    s = 0.02
    assert gaussian_loglik(0.0, s) == pytest.approx(-math.log(s) - 0.5 * math.log(2 * math.pi))
    assert gaussian_loglik(s, s) - gaussian_loglik(0.0, s) == pytest.approx(-0.5)


def test_mixture_never_falls_below_the_outlier_floor():
    r = np.linspace(-math.pi, math.pi, 101)
    m = mixture_loglik(r, 0.02, 0.05)
    assert np.all(m >= math.log(0.05 / (2 * math.pi)) - 1e-12)
    assert mixture_loglik(0.0, 0.02, 0.05) == pytest.approx(gaussian_loglik(0.0, 0.02) + math.log(0.95), abs=1e-3)


def test_likelihood_wraps_the_residual_and_adds_gps_noise_by_range():
    lik = BearingLikelihood("gaussian", 0.0)
    # Particle due west (bearing pi); measurement -pi + 0.01: the residual is 0.01, not 2 pi - 0.01.
    assert lik.log(np.array([[-100.0, 0.0]]), 0.0, 0.0, -math.pi + 0.01, 0.01)[0] == pytest.approx(
        gaussian_loglik(0.01, 0.01)
    )
    with_gps = BearingLikelihood("gaussian", 0.0, gps_sigma_m=3.0)
    s_eff = math.sqrt(0.01**2 + (3.0 / 100.0) ** 2)
    assert with_gps.log(np.array([[100.0, 0.0]]), 0.0, 0.0, 0.0, 0.01)[0] == pytest.approx(gaussian_loglik(0.0, s_eff))


def test_the_mixture_floor_is_the_naive_formula_to_the_last_bit():
    """mixture_loglik raises g before exp (exp is slow where it underflows): the same value as log(exp(g) + c)."""
    rng = np.random.default_rng(0)
    resid = np.concatenate([rng.normal(0, 0.02, 500), rng.uniform(-math.pi, math.pi, 500), [0.0, math.pi, -math.pi]])
    for sigma in (1e-4, 0.01, 0.05, 1.0):
        for eps in (1e-6, 0.1, 0.5):
            g = gaussian_loglik(resid, sigma) + math.log1p(-eps)
            naive = np.log(np.exp(g) + eps / (2 * math.pi))
            assert np.array_equal(mixture_loglik(resid, sigma, eps), naive)


def test_one_point_likelihood_equals_the_general_code():
    """A filter step's one point takes a plain-float path; it agrees with the general (array) code to 1e-12 for
    both likelihoods, with and without GPS terms, and for particles at the antenna or run off to 1e200 m."""
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.normal(0, 800, (300, 2)), [[10.0, -20.0], [10.5, -20.0], [1e200, 5.0], [-3e150, 2e150]]])
    for kind, eps in (("mixture", 0.05), ("mixture", 1e-6), ("gaussian", 0.0)):
        for gps_m in (0.0, 3.0):
            lik = BearingLikelihood(kind, eps, gps_sigma_m=gps_m)
            for _ in range(20):
                theta, sigma = float(rng.uniform(-math.pi, math.pi)), float(rng.uniform(1e-3, 0.3))
                gps = float(rng.choice([0.0, rng.uniform(0.5, 20.0)]))
                fast = lik.log(x, 10.0, -20.0, theta, sigma, gps)
                with np.errstate(over="ignore"):  # the reference squares 1e200
                    ref = lik.log(x, 10.0, -20.0, np.array(theta), np.array(sigma), np.array(gps))
                assert np.all(np.isfinite(fast))
                np.testing.assert_allclose(fast, ref, rtol=1e-12, atol=1e-12)


def _filter(deferred=False, **kw):
    cfg = LocalizerConfig(seed=1, num_particles=kw.pop("n", 4), **kw)
    return make_filter(cfg, np.random.default_rng(cfg.seed), EmitterModel(cfg), deferred)


def test_ess_estimate_and_covariance_by_hand():
    f = _filter(algorithm="sir")
    f.initialise(np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]]), [1, 1], np.eye(2) * 1e6)
    assert f.ess() == pytest.approx(4.0)
    mean, cov = f.estimate()
    assert mean == pytest.approx([1.0, 1.0]) and cov == pytest.approx(np.eye(2))
    f.logw = np.array([0.0, -np.inf, -np.inf, -np.inf])
    assert f.ess() == pytest.approx(1.0)
    assert f.estimate()[0] == pytest.approx([0.0, 0.0])


def test_log_domain_weights_survive_likelihoods_that_underflow():
    f = _filter(algorithm="sir", likelihood="gaussian", n=3, process_noise_m=0.0)
    f.initialise(np.array([[1000.0, 10.0], [1000.0, 200.0], [-1000.0, 0.0]]), [0, 0], np.eye(2) * 1e8)
    p = ObservationPoint(0.0, 0.0, 0.0, 0.0, 1e-4, 1)  # bearing due east, 0.006 deg sigma
    assert f.update(p)
    w = f.weights
    assert np.all(np.isfinite(w)) and w.sum() == pytest.approx(1.0)
    assert np.all(np.abs(f.x[:, 1]) <= 10.0)  # only the particle on the bearing line survives


def test_a_point_no_particle_can_explain_is_skipped_and_nothing_changes():
    f = _filter(algorithm="sir", process_noise_m=0.0)
    x0 = np.array([[0.0, 1.0], [1.0, 0.0], [2.0, 2.0], [3.0, 1.0]])
    f.initialise(x0, [0, 0], np.eye(2))
    assert not f.update(ObservationPoint(0.0, 0.0, 0.0, float("nan"), 0.01, 1))
    assert f.skipped == 1 and np.array_equal(f.x, x0) and np.all(f.logw == 0)


@pytest.mark.slow
def test_mcmc_moves_keep_the_target_distribution():
    """With no bearings the posterior is the Gaussian prior: the fish moves must leave it invariant."""
    f = _filter(n=4000)
    assert isinstance(f.kernel, AfsaMoves)
    mean, cov = np.array([100.0, -50.0]), np.array([[400.0, 150.0], [150.0, 100.0]])
    rng = np.random.default_rng(2)
    f.initialise(rng.multivariate_normal(mean, cov, 4000), mean, cov)
    f.spread = cov
    for _ in range(5):
        f.move(f.sweeps)
    assert 0.2 < f.acceptance < 0.95
    assert f.x.mean(axis=0) == pytest.approx(mean, abs=1.5)
    assert np.cov(f.x.T) == pytest.approx(cov, rel=0.12, abs=10)


class ScaleMixture:
    """A static posterior that is a marginal over two noise hypotheses: x | h ~ N(MEAN, s_h^2 COV), h = 0 or 1
    with equal prior, so the marginal's covariance is the mean of s_h^2 times COV and its tails are s_1's."""

    dim = 2
    scales = np.array([0.5, 2.0])
    mean, cov = np.array([100.0, -50.0]), np.array([[400.0, 150.0], [150.0, 100.0]])
    history: list = []

    def set_prior(self, mean, cov):
        pass

    def hypotheses_log_joint(self, x):
        d = x - self.mean
        q = np.einsum("ni,ij,nj->n", d, np.linalg.inv(self.cov), d)
        return -0.5 * q[:, None] / self.scales**2 - 2.0 * np.log(self.scales)

    def log_posterior_given(self, x, h):
        return self.hypotheses_log_joint(x)[np.arange(len(x)), h]

    def log_posterior(self, x):
        return np.logaddexp.reduce(self.hypotheses_log_joint(x), axis=1)


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["afsa", "espf", "gfapf", "agapf", "sir"])
def test_mcmc_moves_on_place_and_noise_together_keep_the_marginal(algorithm):
    """A latent noise: the sweeps draw each particle's hypothesis, then move it given that one; a cloud of the
    marginal stays one (covariance, and the share in the heavy tail), where moving every particle under one
    hypothesis, or losing whose hypothesis is whose, would not."""
    model = ScaleMixture()
    cfg = LocalizerConfig(seed=5, num_particles=4000, algorithm=algorithm)
    f = make_filter(cfg, np.random.default_rng(5), model)
    rng = np.random.default_rng(6)
    h = rng.integers(0, 2, 4000)
    f.initialise(model.mean + rng.multivariate_normal(np.zeros(2), model.cov, 4000) * model.scales[h][:, None])
    f.spread = np.mean(model.scales**2) * model.cov
    for _ in range(5):
        f.move(f.sweeps)
    assert 0.1 < f.acceptance < 0.95
    assert f.x.mean(axis=0) == pytest.approx(model.mean, abs=2.5)
    assert np.cov(f.x.T) == pytest.approx(np.mean(model.scales**2) * model.cov, rel=0.12, abs=15)
    d = f.x - model.mean
    far = np.einsum("ni,ij,nj->n", d, np.linalg.inv(model.cov), d) > 9.0  # beyond 3 sigma: only h = 1 gets there
    assert np.mean(far) == pytest.approx(0.5 * math.exp(-9.0 / 8.0), abs=0.025)


@pytest.mark.slow
def test_mcmc_moves_pull_a_misplaced_school_towards_the_posterior():
    f = _filter(n=500)
    mean, cov = np.array([0.0, 0.0]), np.eye(2) * 25.0
    f.initialise(np.full((500, 2), 30.0) + np.random.default_rng(0).normal(size=(500, 2)), mean, cov)
    f.spread = cov
    for _ in range(20):
        f.move(f.sweeps)
    assert np.linalg.norm(f.x.mean(axis=0)) < 6.0


def test_paper_school_swims_towards_the_bearing_line():
    cfg = LocalizerConfig(seed=3, num_particles=200).with_changes(
        **{"afsa.variant": "paper", "afsa.visual": 5.0, "afsa.step": 2.0}
    )
    f = make_filter(cfg, np.random.default_rng(3), EmitterModel(cfg))
    rng = np.random.default_rng(4)
    x = np.column_stack([rng.uniform(900, 1100, 200), rng.uniform(-60, 60, 200)])
    p = ObservationPoint(0.0, 0.0, 0.0, 0.0, math.radians(1.0), 1)  # the line north = 0
    moved = f.swim(x, p)
    assert np.mean(np.abs(moved[:, 1])) < np.mean(np.abs(x[:, 1])) - 1.0
    assert 1 <= f.school_rounds <= cfg.afsa.max_iterations


def test_uniform_disc_is_inside_the_unit_disc_and_centred():
    d = uniform_disc(np.random.default_rng(0), (20000,))
    r = np.hypot(d[:, 0], d[:, 1])
    assert r.max() <= 1.0 and d.mean(axis=0) == pytest.approx([0, 0], abs=0.02)
    assert np.mean(r < 0.5) == pytest.approx(0.25, abs=0.02)  # uniform in area


def test_a_filter_refuses_a_model_without_the_capability_it_needs():
    """The model contract: AFSA needs a static posterior (its school and the MCMC moves evaluate it), the UPF
    family an unscented form and a transition density; make_filter says which is missing."""
    from aoa_localizer.filters import ModelMismatch
    from aoa_localizer.models.benchmarks import BearingsOnlyModel, GrowthModel

    paper = {f"{a.group}.variant": "paper" for a in REGISTRY.values()}
    with pytest.raises(ModelMismatch, match=r"afsa \(afsa.variant paper\) needs a model with StaticPosterior"):
        make_filter(LocalizerConfig(algorithm="afsa").with_changes(**paper), np.random.default_rng(0), GrowthModel())
    for algorithm in ("upf", "upfde"):
        with pytest.raises(ModelMismatch, match=f"{algorithm} .*needs a model with UnscentedForm.*BearingsOnlyModel"):
            make_filter(LocalizerConfig(algorithm=algorithm).with_changes(**paper), np.random.default_rng(0),
                        BearingsOnlyModel())
    for algorithm in ("sir", "espf", "gfapf", "pfde", "agapf", "upf"):
        cfg = LocalizerConfig(algorithm=algorithm, num_particles=10).with_changes(**paper)
        assert make_filter(cfg, np.random.default_rng(0), GrowthModel()).name == algorithm
        # the default (mcmc) variant needs the static posterior, and says the paper variant may run
        with pytest.raises(ModelMismatch, match="variant: paper, may run on it"):
            make_filter(LocalizerConfig(algorithm=algorithm), np.random.default_rng(0), GrowthModel())


def _counting_filter(realtime, sweep_cost_us=0.0, n=200):
    """A scheduler and an n-particle filter it took, whose sweeps are counted in `made`, each as the particles it
    moved (each metered at `sweep_cost_us`, the model's own looks unmetered)."""
    scheduler = Scheduler(realtime, lambda reason: None)
    f = _filter(n=n, deferred=True)
    made = []
    real = f.sweep

    def sweep(target, z):
        made.append(f.n)
        slices.charge(slices.Cost(sweep_cost_us, 0.0), 0)
        return real(target, z)

    f.sweep = sweep
    rng = np.random.default_rng(0)
    f.initialise(rng.normal(0.0, 10.0, (n, 2)), [0, 0], np.eye(2) * 1e6)
    f.spread = np.eye(2) * 100.0
    return scheduler, f, made


def _vague(k):
    """A point that barely informs (sigma 1 rad): no resampling."""
    return ObservationPoint(float(k), 500.0, 500.0, 0.0, 1.0, 1)


def _resampled(scheduler, f):
    """The end of a step that resampled, as update() makes it."""
    f.resample()
    f.resampled = True
    f.after_resample(_vague(-1))
    scheduler.stepped(f)


def _point(scheduler, f, k):
    assert f.update(_vague(k)) and not f.resampled
    scheduler.stepped(f)


def _sweeps_per_call(scheduler, f, made, points):
    """Sweeps made at a resampling, then at each of `points` points without one."""
    counts = []
    _resampled(scheduler, f)
    counts.append(len(made))
    for k in range(points):
        made.clear()
        _point(scheduler, f, k)
        counts.append(len(made))
    return counts


def _debtor(f, modes_moves):
    """What the scheduler is given of a track: its filter, and a proposal whose moves (counted in `modes_moves`,
    not made) stand for the move on a check's modes."""
    proposal = object()
    real = f.rejuvenate

    def rejuvenate(sweeps, with_proposal=None):
        if with_proposal is proposal:
            modes_moves.append(sweeps)
            return None
        return real(sweeps, with_proposal)

    f.rejuvenate = rejuvenate
    return f, proposal


def test_realtime_sweeps_are_owed_to_the_scheduler_and_made_between_or_at_the_next_points():
    """Under `realtime` the scheduler takes a resampling's sweeps as owed: none at the resampling, then one at each
    following point until all `sweeps` are made, unless move_one() (between points) made them first; a resampling
    that comes before the debt is paid pays it, so no cloud gets fewer sweeps than without the spreading."""
    scheduler, f, made = _counting_filter(True)
    assert _sweeps_per_call(scheduler, f, made, 6) == [0, 1, 1, 1, 1, 1, 0]
    made.clear()
    _resampled(scheduler, f)  # none now, 5 owed
    _resampled(scheduler, f)  # resampled again before the debt is paid: the 5 owed now, 5 more owed
    assert len(made) == 5 and scheduler.debt(f).sweeps == 5

    scheduler, f, made = _counting_filter(True)
    modes_moves: list[int] = []
    debtor = _debtor(f, modes_moves)
    _point(scheduler, f, 0)
    assert not scheduler.move_one([debtor]) and not made  # nothing owed
    _resampled(scheduler, f)
    assert scheduler.move_one([debtor]) and scheduler.move_one([debtor]) and len(made) == 2  # one per call
    assert scheduler.owed(f) == 3
    made.clear()
    _point(scheduler, f, 1)
    assert len(made) == 1 and scheduler.owed(f) == 2  # the next point makes one of the rest
    made.clear()
    scheduler.owe_modes(f)
    assert scheduler.owed(f) == 3 and scheduler.move_one([debtor]) and not made  # the modes' move first ...
    assert modes_moves == [1] and scheduler.owed(f) == 2  # ... with the track's proposal
    assert not scheduler.move_one([(None, None)])  # a track without a filter owes nothing
    assert scheduler.debt(_filter(n=200)).sweeps == 0  # a new filter owes nothing


def _unmetered_looks(monkeypatch):
    """The model's looks (LOOKS) charge nothing: only what a test charges is metered."""
    real = slices.charge
    monkeypatch.setattr(slices, "charge", lambda cost, elements: None if cost is slices.LOOKS else real(cost, elements))


def test_reproducible_sweeps_fill_the_calls_budget_and_the_rest_go_to_the_next_points(monkeypatch):
    """Under `reproducible` a call makes the owed sweeps while its metered cost and one more sweep's stay under
    SWEEP_BUDGET_US, at least one a call unless a job's pieces came first or the call spent half the budget; the rest
    at the points that follow. A resampling before the debt is paid owes its own sweeps instead. move_one() (idle
    time) makes none: a reproducible run follows its points alone. pay_all() makes the rest."""
    _unmetered_looks(monkeypatch)  # only the test's cost is metered
    sweep_us = 1500.0  # 5000 us holds three (4500), not four
    scheduler, f, made = _counting_filter(False, sweep_us, n=SWEEP_PART)  # whole sweeps
    assert _sweeps_per_call(scheduler, f, made, 3) == [3, 2, 0, 0]

    made.clear()
    with slices.one_call():
        slices.charge(slices.Cost(3600.0, 0.0), 0)  # a step over half the budget, a sweep would pass it: none
        _resampled(scheduler, f)
    assert not made and scheduler.debt(f).sweeps == 5
    with slices.one_call():
        slices.charge(slices.Cost(2000.0, 0.0), 0)  # a dear step: the sweep it must make, and no other
        _resampled(scheduler, f)
    assert len(made) == 1 and scheduler.debt(f).sweeps == 4
    made.clear()
    with slices.one_call():  # two points closed by one input: the first spends the budget (3 sweeps, 4500 us) ...
        _resampled(scheduler, f)
        _resampled(scheduler, f)  # ... the second's five are owed (a sweep a call, not one a point)
    assert len(made) == 3 and scheduler.debt(f).sweeps == 5
    made.clear()
    with slices.one_call(slices.Call()):  # a job's pieces came first in the call and spent 4000 us: none now
        slices.charge(slices.Cost(4000.0, 0.0), 0)
        slices.current_call().pieces = 1
        _resampled(scheduler, f)
    assert not made and scheduler.debt(f).sweeps == 5
    _resampled(scheduler, f)  # the new resampling's five replace the 5 left: three of them now
    assert len(made) == 3 and scheduler.debt(f).sweeps == 2
    made.clear()
    assert not scheduler.move_one([(f, None)]) and not made and scheduler.owed(f) == 2
    scheduler.pay_all(f)
    assert len(made) == 2 and scheduler.owed(f) == 0


def test_reproducible_sweeps_of_a_large_cloud_are_made_a_part_at_a_time(monkeypatch):
    """Under `reproducible` a cloud of more than SWEEP_PART particles is swept SWEEP_PART particles at a time (the
    budget counts the parts): a sweep's parts are a permutation of the cloud, and a part leaves every other
    particle as it was. pay_all() makes the rest as whole sweeps."""
    _unmetered_looks(monkeypatch)
    scheduler, f, made = _counting_filter(False, 1500.0, n=250)
    parts = []
    real_move = f.move

    def move(count, part=None):
        parts.append(None if part is None else np.array(part))
        before = f.x.copy()
        real_move(count, part)
        if part is not None:
            rest = np.setdiff1d(np.arange(f.n), part)
            assert np.array_equal(f.x[rest], before[rest])

    f.move = move
    _resampled(scheduler, f)
    assert made == [100, 100, 50] and scheduler.debt(f).sweeps == 4  # the first sweep, whole, in three parts
    assert np.array_equal(np.sort(np.concatenate(parts)), np.arange(250))
    made.clear()
    with slices.one_call():
        slices.charge(slices.Cost(2000.0, 0.0), 0)  # a dear step: one part
        _point(scheduler, f, 0)
    assert made == [100] and scheduler.debt(f).sweeps == 4 and scheduler.debt(f).at == 100
    made.clear()
    _point(scheduler, f, 1)  # the sweep goes on where it stopped, then the next begins
    assert made == [100, 50, 100] and scheduler.debt(f).sweeps == 3 and scheduler.debt(f).at == 100
    made.clear()
    scheduler.pay_all(f)
    assert made == [250, 250, 250] and scheduler.owed(f) == 0


def test_the_cloud_summary_is_made_once_per_cloud_and_follows_a_replaced_cloud():
    """Weights, ESS, mean and covariance are made once per cloud (a step reads them several times) and are what a
    fresh computation gives; a replaced cloud or new weights get a new summary; the cloud cannot be changed in
    place behind its summary's back."""
    f = _filter(algorithm="sir", n=4)
    f.initialise(np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]]), [1, 1], np.eye(2) * 1e6)
    first = f.estimate()
    assert f.estimate()[1] is first[1] and f.weights is f.weights
    f.logw = np.log(np.array([0.7, 0.1, 0.1, 0.1]))
    mean, cov = f.estimate()
    assert mean == pytest.approx([0.4, 0.4]) and cov.ravel() == pytest.approx([0.64, 0.24, 0.24, 0.64])
    assert f.ess() == pytest.approx(1.0 / (0.49 + 0.03))
    f.x = f.x + 10.0
    assert f.estimate()[0] == pytest.approx([10.4, 10.4]) and f.finite()
    with pytest.raises(ValueError):
        f.x[0, 0] = 5.0
    with np.errstate(all="ignore"):
        f.x = np.array([[0.0, 0.0], [np.inf, 0.0], [0.0, 2.0], [2.0, 2.0]])
        assert not f.finite()  # a particle run off to infinity, whatever its weight
        f.x = np.array([[0.0, 0.0], [1e300, 0.0], [0.0, 2.0], [2.0, 2.0]])
        assert np.isfinite(f.x).all() and not f.finite()  # finite particles, but the covariance overflows
        f.x, f.logw = np.zeros((4, 2)), np.array([0.0, np.nan, 0.0, 0.0])
        assert not f.finite()  # a NaN weight: the mean is NaN


def gaussian_loglik(residual, sigma):
    """log N(residual; 0, sigma^2): the paper's likelihood (eq. 24) with its normalising constant, the reference
    the engine's variance form is held to."""
    return gaussian_loglik_var(residual, np.square(sigma))
