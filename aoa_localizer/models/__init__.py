"""State-space models the particle-filter skeleton runs: the contract (base.py) and the papers' benchmark models.
The emitter problem's model is the engine's (engine/inference/emitter_model.py)."""
from aoa_localizer.models.base import StateSpaceModel

__all__ = ["StateSpaceModel"]
