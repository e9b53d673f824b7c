"""Simulated vehicles, fleets, goal drives and surveys, and the evaluation that runs them through a Localizer
(not part of the engine: nothing in engine/ imports this)."""
