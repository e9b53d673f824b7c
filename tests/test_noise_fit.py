"""A check's joint fit of place and noise (checks.fit_noise): each distinct candidate place is fitted, a candidate
in the basin of a place already fitted is not fitted again."""
import math

import numpy as np

from aoa_localizer import LocalizerConfig
from aoa_localizer.engine import checks
from aoa_localizer.engine.global_search import Robust
from aoa_localizer.engine.noise import NoiseModel
from aoa_localizer.engine.point_batch import PointBatch
from aoa_localizer.engine.preprocess import Group
from aoa_localizer.engine.types import Reading

EMITTER = np.array([1200.0, 800.0])


def drive(rng: np.random.Generator, sigma: float) -> list[Group]:
    """30 points of 8 readings along a road past the emitter, the bearings' noise `sigma` (rad) while the
    readings say 0.02."""
    out = []
    for k in range(30):
        east, north = 40.0 * k, 0.002 * (40.0 * k) ** 1.5
        true = math.atan2(EMITTER[1] - north, EMITTER[0] - east)
        out.append(Group(Reading(float(8 * k + i), float(true + rng.normal(0.0, sigma)), 80.0, 0.02, east, north)
                         for i in range(8)))
    return out


def test_a_candidate_in_a_fitted_places_basin_is_not_fitted_again_and_changes_nothing(monkeypatch):
    cfg = LocalizerConfig()
    batch = PointBatch(drive(np.random.default_rng(3), 0.06), cfg)
    rob = Robust(cfg.outlier_prob, cfg.gps_sigma_m)
    fits = []
    fit = NoiseModel.fit
    monkeypatch.setattr(NoiseModel, "fit", lambda self, *a: fits.append(1) or fit(self, *a))

    def run(candidates):
        fits.clear()
        out = checks.fit_noise(batch, NoiseModel(cfg.outlier_prob), rob, candidates, False)
        return out, len(fits)

    near = EMITTER + np.array([3.0, -2.0])
    (noise, place, _), alone = run([near])
    (noise2, place2, _), with_twin = run([near, near + np.array([0.05, 0.05])])
    assert with_twin == alone  # the twin is in the first fit's basin
    assert np.array_equal(place2, place) and np.array_equal(noise2.k, noise.k)
    assert np.hypot(*(place - EMITTER)) < 20.0
    assert 2.0 < float(np.median(noise.k)) < 4.5  # the noise is 3x what the readings say, and the fit finds it
    far = np.array([-3000.0, 4000.0])  # behind the road: another basin, fitted
    (_, place3, _), with_far = run([near, far])
    assert with_far == alone + 2 and np.array_equal(place3, place)
