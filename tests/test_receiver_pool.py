"""One receiver over many channels (issue 50, the filter path): the channels that calibrated their noise give the
prior of one that has not, and /diagnostics, the report and replay say what they pooled."""
import math

import numpy as np
import pytest

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.noise import N_BANDS, NoiseModel
from aoa_localizer.engine.inference.receiver import NoiseGrid
from aoa_localizer.engine.inference.receiver_pool import CHANNEL_SPREAD_LOG_SD, pooled_noise
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.reporting.words import robustness_lines


def _fitted(k_by_band: dict[int, float], readings: float = 50.0) -> NoiseModel:
    m = NoiseModel(0.05)
    for band, k in k_by_band.items():
        m.k[band], m.readings[band] = k, readings
    m.fits = 1
    return m


def test_the_pool_is_the_geometric_mean_of_the_fitted_channels_by_hand():
    """Each channel's scale: its bands' log k averaged by their readings; the pool: their geometric mean, with the
    assumed spread while fewer than three channels show theirs, and their own spread from three on."""
    assert pooled_noise([NoiseModel(0.05)]) is None  # never fitted: nothing to pool
    one = pooled_noise([_fitted({0: 2.0, 1: 8.0})])  # equal readings: sqrt(2 * 8) = 4
    assert one.scale == pytest.approx(4.0) and one.channels == 1 and one.readings == 100
    assert one.log_sd == pytest.approx(CHANNEL_SPREAD_LOG_SD * math.sqrt(2.0))
    three = pooled_noise([_fitted({2: 1.0}), _fitted({2: math.e}), _fitted({N_BANDS: math.e**2})])
    assert three.scale == pytest.approx(math.e) and three.log_sd == pytest.approx(1.0 * math.sqrt(1 + 1 / 3))


def test_a_pooled_prior_is_centred_on_the_pool_and_keeps_the_configured_scales():
    """The hypotheses are the same sigmas on the configured one; only their prior moves to the pool's scale."""
    weak, pooled = NoiseGrid.weak(1.0), NoiseGrid.weak(1.0, pooled_noise([_fitted({3: 10.0})]))
    assert np.array_equal(weak.scale, pooled.scale)
    mode = pooled.scale[np.argmax(pooled.log_prior)]
    assert abs(math.log(mode / 10.0)) <= 0.5 * math.log(1.9) + 1e-9  # the grid point nearest x10
    assert weak.scale[np.argmax(weak.log_prior)] == pytest.approx(1.0, rel=0.5)


def test_a_new_channel_starts_from_the_receivers_pool_once():
    """A channel opened after another calibrated takes the pool at its first search and keeps it; the Localizer
    names the pool (replay's lines, the node's /diagnostics) once two channels were heard."""
    loc = Localizer(LocalizerConfig(seed=1))
    loc.add_fix(1.0, 39.1, 117.2)
    loc.add_fix(2.0, 39.1, 117.2)
    loc.add_bearing(1.5, 10.0, 90.0, frequency_hz=433e6)
    first = loc._channels.live["f433000000"]
    first.track.calibration.noise = _fitted({4: 3.0})
    assert loc.view().receiver_noise is None  # one channel: its own calibration says it all
    loc.add_bearing(1.6, 50.0, 90.0, frequency_hz=446e6)
    second = loc._channels.live["f446000000"].track.calibration
    grid = second.noise_prior()
    assert second.pooled is not None and second.pooled.scale == pytest.approx(3.0)
    first.track.calibration.noise = _fitted({4: 9.0})  # later calibrations do not move a prior already taken
    assert second.noise_prior() is grid
    assert any(line.startswith("the receiver over its channels: 9.00x") for line in robustness_lines(loc))
