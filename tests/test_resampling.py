import numpy as np
import pytest

from aoa_localizer.filters.resampling import SCHEMES, residual, systematic


@pytest.mark.parametrize("name", sorted(SCHEMES))
def test_each_scheme_returns_n_valid_indices_in_proportion(name):
    w = np.array([0.1, 0.2, 0.3, 0.4])
    counts = np.zeros(4)
    rng = np.random.default_rng(5)
    for _ in range(500):
        idx = SCHEMES[name](w, rng)
        assert idx.shape == (4,) and idx.min() >= 0 and idx.max() <= 3
        counts += np.bincount(idx, minlength=4)
    assert counts / counts.sum() == pytest.approx(w, abs=0.03)


@pytest.mark.parametrize("name", sorted(SCHEMES))
def test_a_seed_reproduces_the_draw(name):
    w = np.random.default_rng(0).dirichlet(np.ones(50))
    a = SCHEMES[name](w, np.random.default_rng(7))
    b = SCHEMES[name](w, np.random.default_rng(7))
    assert np.array_equal(a, b)


def test_residual_keeps_the_whole_copies():
    idx = residual(np.array([0.5, 0.25, 0.25]), np.random.default_rng(0))  # N=3: floor(1.5, .75, .75) = 1, 0, 0
    assert np.sum(idx == 0) >= 1 and idx.size == 3
    idx = residual(np.array([0.5, 0.25, 0.25, 0.0]), np.random.default_rng(0))  # N=4: exactly 2, 1, 1, 0
    assert sorted(idx.tolist()) == [0, 0, 1, 2]


def test_systematic_with_equal_weights_keeps_every_particle_once():
    idx = systematic(np.full(8, 1 / 8), np.random.default_rng(3))
    assert sorted(idx.tolist()) == list(range(8))


def test_a_dominant_particle_takes_all_slots():
    w = np.array([1e-300, 1.0 - 2e-300, 1e-300])
    for name, scheme in SCHEMES.items():
        assert set(scheme(w, np.random.default_rng(1)).tolist()) == {1}, name
