"""Why an input was not used: every reason the engine counts, with its words (docs/design.md's table is written from
them), and the counter that keeps them."""
from __future__ import annotations

import logging
from collections import Counter, deque
from enum import StrEnum

log = logging.getLogger("aoa_localizer")

_RECENT_INPUTS = 50  # inputs whose fate the status watches ...
_RECENT_MIN = 20  # ... once at least this many came


class Reason(StrEnum):
    """A reason an input was not used. Members are their names as strings: `rejected["gps_gap"]` finds
    `Reason.GPS_GAP`'s count."""

    words: str

    def __new__(cls, value: str, words: str):
        member = str.__new__(cls, value)
        member._value_ = value
        member.words = words
        return member

    BAD_STAMP = "bad_stamp", "stamp is not a finite number"
    BAD_AZIMUTH = "bad_azimuth", "azimuth is NaN or infinite"
    BAD_SIGMA = "bad_sigma", "a reading's own sigma (sigma_deg) given but not a number in [0.001, 180] deg"
    BAD_QUALITY = "bad_quality", "quality outside 0..100"
    LOW_QUALITY = "low_quality", "quality below quality_min"
    BEARING_OUT_OF_ORDER = "bearing_out_of_order", "bearing stamp older than the previous bearing"
    BEARING_REPEATED = "bearing_repeated", "bearing stamp equal to the previous bearing"
    BEARING_STAMP_JUMP = ("bearing_stamp_jump",
                          "bearing stamp more than max_stamp_jump_s ahead of the DF stream: not adopted")
    CLOCK_JUMP = "clock_jump", "a bearing of the old timeline still waiting for a fix when the DF clock jumped"
    BEFORE_FIRST_FIX = "before_first_fix", "no GPS fix at or before the bearing"
    GPS_GAP = "gps_gap", "the fixes around the bearing are more than gps_max_gap_s apart"
    NO_FIX_AFTER = "no_fix_after", "no later fix came to bracket the bearing before the end of data"
    HEADING_UNKNOWN = ("heading_unknown", "a vehicle-relative bearing with no heading at its stamp: too slow for a "
                       "course, or no IMU heading, for longer than heading_hold_s")
    BAD_FREQUENCY = "bad_frequency", "frequency negative, infinite or above 1 THz (0 or NaN: the default channel)"
    CHANNEL_LIMIT = "channel_limit", "a new frequency while max_channels channels are tracked"
    CHANNEL_RETIRED = ("channel_retired",
                       "a bearing still waiting for a fix when its channel was retired (channel_timeout_s)")
    POINT_OUTLIER = "point_outlier", "wild reading inside an observation point (point_gate_sigma)"
    INIT_BUFFER_FULL = "init_buffer_full", "geometry stayed too poor to start; oldest points dropped (init_max_points)"
    EMITTER_MOVED = ("emitter_moved", "bearings from before the emitter moved, dropped when the track re-started "
                     "from the recent ones")
    WEIGHTS_DEGENERATE = "weights_degenerate", "no particle could explain the point; measurement skipped"
    INTERNAL_ERROR = "internal_error", "an unexpected error in the filter; measurement skipped, state kept"
    FILTER_DIVERGED = ("filter_diverged",
                       "the filter's particles or estimate were not finite; not published, the filter restarts")
    COVARIANCE_DEGENERATE = ("covariance_degenerate",
                             "the filter's covariance was not positive definite: estimate not published")
    FIX_BAD_STAMP = "fix_bad_stamp", "fix stamp is not a finite number"
    FIX_NO_FIX = "fix_no_fix", "NavSatFix status below STATUS_FIX"
    FIX_BAD_POSITION = "fix_bad_position", "fix latitude/longitude NaN, infinite or out of range"
    FIX_OUT_OF_ORDER = "fix_out_of_order", "fix stamp older than the previous fix"
    FIX_REPEATED = "fix_repeated", "fix stamp equal to the previous fix"
    FIX_STAMP_JUMP = "fix_stamp_jump", "fix stamp more than max_stamp_jump_s ahead of the GPS stream: not adopted"
    FIX_BAD_ALTITUDE = "fix_bad_altitude", "fix altitude outside -1000..20000 m"
    FIX_NEAR_POLE = "fix_near_pole", "fix within 0.01 deg of a pole (no local north)"
    FIX_NULL_ISLAND = "fix_null_island", "fix at exactly 0, 0 (a receiver without a fix)"
    FIX_BEYOND_MAP = ("fix_beyond_map", "fix or station more than 3000 km from the map's datum (restart there, or set "
                      "datum_lat/datum_lon near it)")
    FIX_UNCONFIRMED = ("fix_unconfirmed", "a first fix the next fix contradicts (farther than 100 m + 150 m/s): not "
                       "taken as the datum")
    BAD_HEADING = "bad_heading", "heading stamp or yaw is not a finite number"
    HEADING_OUT_OF_ORDER = "heading_out_of_order", "heading stamp not after the previous heading"
    HEADING_IGNORED = ("heading_ignored",
                       "a heading given while bearing_reference is not `vehicle` or heading_source is not `imu`")


REASONS = {reason.value: reason.words for reason in Reason}
# The reasons a GPS fix is refused for (the rest refuse bearings and headings): /diagnostics counts them apart
FIX_REASONS = frozenset({Reason.FIX_BAD_STAMP, Reason.FIX_NO_FIX, Reason.FIX_BAD_POSITION, Reason.FIX_OUT_OF_ORDER,
                         Reason.FIX_REPEATED, Reason.FIX_STAMP_JUMP, Reason.FIX_BAD_ALTITUDE, Reason.FIX_NEAR_POLE,
                         Reason.FIX_NULL_ISLAND, Reason.FIX_BEYOND_MAP, Reason.FIX_UNCONFIRMED})


def table() -> str:
    """The reasons as a markdown table (docs/design.md, "Bad input")."""
    return "\n".join(["| reason | what |", "|---|---|"] + [f"| `{r.value}` | {r.words} |" for r in Reason])


# What every normal run refuses (bearings before the first fix, wild readings inside a point, the last bearings
# with no fix after them): logged at INFO, not as a fault; counted like the rest
ROUTINE = frozenset({Reason.BEFORE_FIRST_FIX, Reason.POINT_OUTLIER, Reason.NO_FIX_AFTER})


class Rejections:
    """The inputs not used, counted by reason (the first of each kind logged), and the fate of the latest inputs, so
    the status can say when most are being refused."""

    def __init__(self):
        self.counts: Counter = Counter()
        self.recent: deque[Reason | None] = deque(maxlen=_RECENT_INPUTS)

    def __call__(self, reason: Reason, count: int = 1) -> None:
        """Count `count` inputs refused for `reason`."""
        for _ in range(count):
            self.counts[reason.value] += 1  # plain strings: what programs print, compare and serialise
            self.recent.append(reason)
            if self.counts[reason.value] == 1:  # the ordinary ones of a normal run are not said as faults
                log.log(logging.INFO if reason in ROUTINE else logging.WARNING,
                        "input not used: %s (%s); further ones are counted", reason.value, reason.words)

    def used(self) -> None:
        """An input was used."""
        self.recent.append(None)

    def refused_line(self) -> str:
        """'; most inputs refused: ...' when more than half of the latest inputs were refused, else ''."""
        refused = [r for r in self.recent if r is not None]
        if len(self.recent) < _RECENT_MIN or len(refused) <= len(self.recent) / 2:
            return ""
        reason, n = Counter(refused).most_common(1)[0]
        return f"; most inputs refused: {reason.value} ({n} of the last {len(self.recent)})"
