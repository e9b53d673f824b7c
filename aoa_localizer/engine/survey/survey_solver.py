"""The survey model the engine's end of data and live survey fixes call: handed to the Localizer
(`survey_solver`), by default aoa_localizer.pooled's, loaded when first called (the layer above the engine, and
heavy: a program that never solves a survey never imports it)."""
from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from aoa_localizer.engine.survey.survey_log import SurveyFix, SurveyRecord

SurveySolver = Callable[[list["SurveyRecord"], str, int], dict[str, "SurveyFix"]]


def pooled_solver(records: list[SurveyRecord], receiver_class: str, max_k: int) -> dict[str, SurveyFix]:
    """aoa_localizer.pooled's survey model of `records` (pooled/end_of_data.py): each channel's fix."""
    return importlib.import_module("aoa_localizer.pooled.end_of_data").solve(records, receiver_class, max_k)
