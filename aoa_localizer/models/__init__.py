"""State-space models the particle-filter skeleton runs: the emitter problem and the papers' benchmark models."""
from .base import StateSpaceModel
from .emitter import EmitterModel

__all__ = ["EmitterModel", "StateSpaceModel"]
