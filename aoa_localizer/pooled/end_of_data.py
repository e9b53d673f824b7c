"""The survey model as the engine's end of data: a Localizer's survey-like channels located as `locate` would.

The engine keeps the bearings of channels heard only from fixed stations or a surveyor (engine/survey/survey_log.py)
and, at `finish()`, hands them here: each channel is an emitter and each Localizer station a station (at each of
its places); which stations share a receiver follows the same rule as a survey file without a `receiver` column
(stations.py), so the API and `locate` give one answer for the same bearings.
"""
from __future__ import annotations

from aoa_localizer.engine.survey.survey_log import SurveyFix, SurveyRecord
from aoa_localizer.pooled.solver import PooledResult, locate_pooled
from aoa_localizer.pooled.stations import SurveyReading


def solve(records: list[SurveyRecord], receiver_class: str, max_k: int) -> dict[str, SurveyFix]:
    """The survey model's fix of every channel it can locate (a channel it refuses keeps the filter's), its
    transmitters counted up to `max_k`."""
    readings = [SurveyReading(r.channel, r.lat, r.lon, r.azimuth_deg, r.station, "", r.sigma_deg, r.stamp)
                for r in records]
    result = locate_pooled(readings, receiver_class, max_k)
    return {e: SurveyFix(f.lat, f.lon, f.cov, f.state, list(f.warnings), f.readings, f.stations,
                         calibration(result, f.receivers), f.hpd, f.count)
            for e, f in result.fixes.items()}


def calibration(result: PooledResult, receivers: list[str]) -> dict:
    """What the survey taught about the receivers of one fix: its group's pooled noise and each receiver's bias."""
    group: dict = next((g for g in result.noise if set(receivers) <= set(g["receivers"])), {})
    biases = {r: {"bias_deg": round(c.bias_deg, 2), "bias_sd_deg": round(c.bias_sd_deg, 2), "emitters": c.emitters,
                  "stations": c.stations}
              for r, c in result.receivers.items() if r in receivers}
    return {"model": "survey", **group, "receiver_biases": biases}
