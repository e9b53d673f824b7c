"""The DF clock check on hand-made points: bearings taken 1 s before their stamps on a drive with a turn."""
import numpy as np

from aoa_localizer.engine.inference import clock_check
from aoa_localizer.engine.inference.global_search import Points, Robust


def best_shift(*args):
    """clock_check.best_shift, every piece made."""
    return clock_check.best_shift(*args)


def _drive(late_s: float, speed: float = 10.0):
    """An L-shaped drive (east 30 s, then north 30 s): on a straight line at constant speed a stamp shift is
    indistinguishable from moving the emitter along the road, so only a turn reveals it."""
    t = np.arange(0.0, 60.0, 1.0)

    def where(time):
        leg1 = np.minimum(time, 30.0)
        return speed * leg1, speed * np.maximum(time - 30.0, 0.0)

    east, north = where(t)
    true_east, true_north = where(t - late_s)  # where the antenna was when the bearing was really taken
    emitter = np.array([150.0, 400.0])
    theta = np.arctan2(emitter[1] - true_north, emitter[0] - true_east)
    sigma = np.full(t.size, np.radians(0.5))
    velocity = np.where((t < 30.0)[:, None], [speed, 0.0], [0.0, speed])
    return Points(east, north, theta, sigma), velocity, emitter


def test_a_known_late_stamp_is_found_and_an_exact_one_is_not():
    """Bearings taken 1 s before their stamps: the positions 1 s earlier (shift -1) fit exactly."""
    pts, velocity, emitter = _drive(late_s=1.0)
    hint = best_shift(pts, velocity, emitter + 20.0, Robust(0.0))
    assert hint is not None and hint.shift_s == -1.0 and hint.gain > 10
    pts, velocity, emitter = _drive(late_s=0.0)
    assert best_shift(pts, velocity, emitter + 20.0, Robust(0.0)) is None
    for late in (1.5, -2.5, 1.75):  # between the whole seconds: the search's halves and quarters find them
        pts, velocity, emitter = _drive(late_s=late)
        hint = best_shift(pts, velocity, emitter + 20.0, Robust(0.0))
        assert hint is not None and abs(hint.shift_s + late) <= 0.25, late


def test_a_straight_drive_or_a_parked_vehicle_gets_no_verdict():
    t = np.arange(0.0, 60.0, 1.0)
    theta = np.arctan2(300.0, 400.0 - 10.0 * (t - 1.0))
    straight = Points(10.0 * t, np.zeros_like(t), theta, np.full(t.size, np.radians(0.5)))
    assert best_shift(straight, np.column_stack([np.full(t.size, 10.0), np.zeros(t.size)]), np.array([420.0, 280.0]),
                      Robust(0.0)) is None
    pts, velocity, emitter = _drive(late_s=1.0)
    assert best_shift(pts, velocity * 0.0, emitter, Robust(0.0)) is None
