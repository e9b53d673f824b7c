"""A vehicle that stops to take its bearings: the stopped form of a drive, and what the engine sends to the survey
model (the data's site part, not the antenna's speed)."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from aoa_localizer import LocalizerConfig
from aoa_localizer.engine.geodesy import wrap_360, wrap_pi
from aoa_localizer.engine.survey.survey_log import site_part_shown
from aoa_localizer.simulation.evaluation import run
from aoa_localizer.simulation.scenarios import SCENARIOS, robustness_cells, simulate
from aoa_localizer.simulation.stops import point_groups, stopped

TRUTH = np.array([400.0, 300.0])


def _rows(rng: np.random.Generator, stops: int = 8, readings: int = 5, sigma_deg: float = 1.0,
          site_deg: float = 0.0, wild_per_stop: int = 0) -> list[tuple]:
    """SurveyLog rows (station, stamp, east, north, map angle, north angle, own sigma, sigma) of a ring of stops."""
    rows = []
    for k in range(stops):
        a = 2 * math.pi * k / stops
        xy = TRUTH + 500.0 * np.array([math.cos(a), math.sin(a)])
        true = math.atan2(TRUTH[1] - xy[1], TRUTH[0] - xy[0])
        site = math.radians(site_deg) * rng.standard_normal()
        for i in range(readings):
            theta = true + site + math.radians(sigma_deg) * rng.standard_normal()
            if i < wild_per_stop:
                theta = rng.uniform(-math.pi, math.pi)
            rows.append(("v", 10.0 * k + 0.1 * i, xy[0], xy[1], float(wrap_pi(theta)), math.pi / 2, math.nan,
                         math.radians(sigma_deg)))
    return rows


def test_clean_stops_show_no_site_part_and_steady_errors_at_each_stop_do():
    for seed in range(5):
        rng = np.random.default_rng(seed)
        assert site_part_shown(_rows(rng)) is False
        assert site_part_shown(_rows(rng, wild_per_stop=1)) is False  # a wild reading a stop is no site error
        assert site_part_shown(_rows(rng, site_deg=5.0)) is True
        assert site_part_shown(_rows(rng, site_deg=5.0, wild_per_stop=1)) is True


def test_a_configured_sigma_off_by_a_factor_shows_no_site_part():
    """The readings' own pairs say how far they scatter: a receiver three times noisier than its sigma says is not
    taken for a site error."""
    rng = np.random.default_rng(3)
    rows = [(*r[:7], r[7] / 3.0) for r in _rows(rng, sigma_deg=3.0)]
    assert site_part_shown(rows) is False


def test_too_few_stops_of_repeated_readings_cannot_show_a_site_part():
    rng = np.random.default_rng(0)
    assert site_part_shown(_rows(rng, stops=3, site_deg=10.0)) is None  # fewer than SITE_PLACES stops
    assert site_part_shown(_rows(rng, readings=1, site_deg=10.0)) is None  # one reading a stop: cannot tell


def test_the_stopped_form_reads_each_point_from_one_place_with_the_same_errors():
    data = simulate("seed", 0)
    still = stopped(data)
    groups = point_groups(data)
    assert len(groups) == SCENARIOS["seed"].points and len(still.fixes) == 2 * len(groups)
    for idx in groups[:5]:
        assert np.ptp(still.sensor_enu[idx], axis=0).max() == 0.0
        assert still.fixes[:, 0].min() <= data.bearings[idx[0], 0]
    # each reading's error against its own place's true azimuth is kept (the frame's north turns little here)
    def errors(d):
        true = np.degrees(np.arctan2(d.emitter_enu[0] - d.sensor_enu[:, 0], d.emitter_enu[1] - d.sensor_enu[:, 1]))
        return wrap_360(d.bearings[:, 1] - true + 180.0) - 180.0
    assert np.allclose(errors(still), errors(data), atol=0.01)


@pytest.mark.slow
def test_a_drive_stopped_at_each_point_gives_the_moving_drives_answer():
    """Stop, read, drive on: clean bearings keep the particle engine's exact answer (not the survey model's)."""
    data = simulate("seed", 1)
    moving = run(data, LocalizerConfig(seed=7))
    still = run(stopped(data), LocalizerConfig(seed=7))
    assert still.estimates[-1].algorithm == moving.estimates[-1].algorithm == "afsa"
    assert still.scores["error"] < 3.0 and abs(still.scores["error"] - moving.scores["error"]) < 1.0
    assert still.scores["inside95"]


@pytest.mark.slow
def test_stops_whose_readings_share_a_steady_error_go_to_the_survey_model():
    """A 5 deg error shared by each stop's readings (multipath at the spot): the survey model, honest."""
    data = stopped(simulate("seed", 2))
    rng = np.random.default_rng(5)
    bearings = data.bearings.copy()
    for idx in point_groups(data):
        bearings[idx, 1] = wrap_360(bearings[idx, 1] + rng.normal(0.0, 5.0))
    result = run(replace(data, bearings=bearings), LocalizerConfig(seed=7))
    assert result.estimates[-1].algorithm == "survey" and result.scores["inside95"]


def test_a_minority_of_stops_far_off_is_no_site_part_and_a_typical_stop_scattering_is():
    """A tenth of the stops taken over by a reflection (their residuals 20 sigmas) is not a site part; every stop
    scattering twice as widely as its readings allow (four times the variance) is."""
    from aoa_localizer.engine.survey.survey_log import _scattered

    rng = np.random.default_rng(0)
    clean = rng.chisquare(1, 100)
    assert not _scattered(clean)
    taken = clean.copy()
    taken[:10] = 400.0
    assert not _scattered(taken)
    assert _scattered(4.0 * clean)


@pytest.mark.slow
def test_a_reflection_at_the_stops_is_never_a_confident_survey_fix():
    """A reflector's ghost in a fifth of the readings, the vehicle stopped at each point: in this run (one of three
    of seeds 0-9 alike) the ghost biases the typical stop and the stops go to the survey model, which takes the
    stations' errors as independent and lands 90 m off with a 30 m ellipse. Its own particle filter, on the same
    readings, is within metres: the two disagree beyond both ellipses, and the fix says so instead of `tracking`."""
    seed = 8
    data = stopped(simulate(robustness_cells()["reflector"], seed))
    result = run(data, LocalizerConfig(seed=1000 + seed))
    final = result.estimates[-1]
    assert final.state.value != "tracking" or result.scores["inside95"]
    if final.algorithm == "survey" and not result.scores["inside95"]:
        assert any("disagree" in w for w in final.warnings)


def test_a_few_stops_a_reflection_took_over_do_not_make_the_others_look_scattered():
    """Exact and honest at once, `reflector` stopped (6 of 20 runs on the survey model, 24x the CRLB): each reading
    comes by a reflection with probability 0.2, so about one stop in ten has the ghost's median; those stops pulled
    the stops' crossing, every other stop then looked scattered, and a site part was shown (4 of these 5 seeds).
    Judged at the crossing they do not pull, the clean stops show none; a real site part on every stop still does."""
    ghost = TRUTH + np.array([250.0, -150.0])

    def road(rng: np.random.Generator, site_deg: float = 0.0) -> list[tuple]:
        rows = []
        for k in range(100):
            xy = np.array([-600.0 + 18.0 * k, -400.0 + 2.0 * k])
            site = math.radians(site_deg) * rng.standard_normal()
            for i in range(3):
                target = ghost if rng.random() < 0.2 else TRUTH
                theta = (math.atan2(target[1] - xy[1], target[0] - xy[0]) + site
                         + math.radians(1.0) * rng.standard_normal())
                rows.append(("v", 10.0 * k + 0.1 * i, xy[0], xy[1], float(wrap_pi(theta)), math.pi / 2, math.nan,
                             math.radians(1.0)))
        return rows

    for seed in range(5):
        assert site_part_shown(road(np.random.default_rng(seed))) is False, seed
        assert site_part_shown(road(np.random.default_rng(seed), site_deg=3.0)) is True, seed
