"""Where the end of data finds the survey model: the package installs aoa_localizer.pooled's solver here when it is
imported, so the engine calls it without importing the layer above it. No imports of its own: the package's
import stays light enough for a program to catch a Ctrl-C within its first tenth of a second."""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from aoa_localizer.engine.survey.survey_log import SurveyFix, SurveyRecord

    SurveySolver = Callable[[list[SurveyRecord], str, int], dict[str, SurveyFix]]

_solver: list[SurveySolver] = []


def install_solver(solver: SurveySolver) -> None:
    """Set the survey model the end of data calls (the package installs aoa_localizer.pooled's)."""
    _solver[:] = [solver]


def solver() -> SurveySolver | None:
    return _solver[0] if _solver else None
