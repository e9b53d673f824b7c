"""State-space models the particle-filter skeleton runs: the emitter problem and the papers' benchmark models."""
from aoa_localizer.models.base import StateSpaceModel
from aoa_localizer.models.emitter import EmitterModel

__all__ = ["EmitterModel", "StateSpaceModel"]
