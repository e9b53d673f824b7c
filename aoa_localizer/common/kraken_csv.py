"""The KrakenSDR "Kraken App" output (DOA_value.html of krakenrf/krakensdr_doa) read into DF records, without ROS.

One line per VFO, as `_sdr/_signal_processing/kraken_sdr_signal_processor.py` writes it (checked at 71c319b):

    timestamp_ms, 360 - theta_0, confidence, max_power_dB, freq_Hz, array type, latency_ms, station_id,
    latitude, longitude, heading, heading, GPS source, R, R, R, R, <the DoA spectrum, one value per degree>

* `timestamp_ms` is the DAQ's IQ-frame stamp, which marks the *end* of the data frame; `latency_ms` is the CPI
  length, the acquisition time. A reading's stamp here is the middle of that interval: timestamp - latency / 2.
* `360 - theta_0` is the DoA clockwise from the array's zero (theta_0 counts the other way); it is **not** turned
  by any heading in this output.
* `confidence` is the spectrum's peak-to-average power ratio in dB (`calculate_doa_papr`), 0 to about 12.
* `heading` is the GPS track (deg clockwise from north) once the receiver moves fast enough, else the last one
  or 0; latitude and longitude are 0, 0 without a GPS fix.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

from aoa_localizer.engine.channels import FREQUENCY_MAX_HZ

FIELDS = 17  # the named fields before the spectrum
_VFOS_KEPT = 256  # frequencies the line filter remembers (a Kraken has at most 16 VFOs); the oldest go first


@dataclass(frozen=True)
class KrakenLine:
    """One VFO's reading from a Kraken App line."""

    stamp: float  # s, the middle of the acquisition interval
    doa_deg: float  # clockwise from the array's zero, [0, 360)
    confidence_db: float
    power_db: float
    frequency_hz: float
    array: str
    latency_ms: float
    station: str
    lat: float
    lon: float
    heading_deg: float

    @property
    def has_gps(self) -> bool:
        """A position (and so a meaningful heading): the receiver writes 0, 0 without a fix."""
        return not (self.lat == 0.0 and self.lon == 0.0)


class MalformedLine(ValueError):
    """A line that is not a Kraken App record: the message says which field."""


def _number(fields: list[str], i: int, name: str) -> float:
    try:
        value = float(fields[i])
    except ValueError:
        raise MalformedLine(f"{name} is not a number: {fields[i]!r}") from None
    if not math.isfinite(value):
        raise MalformedLine(f"{name} is not finite: {fields[i]!r}")
    return value


def parse_line(line: str) -> KrakenLine:
    """A Kraken App line -> KrakenLine; MalformedLine (with the reason) for anything else."""
    fields = [f.strip() for f in line.split(",")]
    if len(fields) < FIELDS:
        raise MalformedLine(f"{len(fields)} fields, a Kraken App line has at least {FIELDS}")
    timestamp_ms = _number(fields, 0, "timestamp")
    latency_ms = _number(fields, 6, "latency")
    lat, lon = _number(fields, 8, "latitude"), _number(fields, 9, "longitude")
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise MalformedLine(f"position {lat}, {lon} out of range")
    frequency_hz = _number(fields, 4, "frequency")
    if not 0 < frequency_hz <= FREQUENCY_MAX_HZ:
        raise MalformedLine(f"frequency {frequency_hz:g} Hz out of range (0, {FREQUENCY_MAX_HZ:g}]")
    return KrakenLine(
        stamp=(timestamp_ms - 0.5 * max(latency_ms, 0.0)) / 1000.0,
        doa_deg=_number(fields, 1, "DoA") % 360.0,
        confidence_db=_number(fields, 2, "confidence"),
        power_db=_number(fields, 3, "power"),
        frequency_hz=frequency_hz,
        array=fields[5],
        latency_ms=latency_ms,
        station=fields[7],
        lat=lat,
        lon=lon,
        heading_deg=_number(fields, 10, "heading") % 360.0,
    )


def quality_from_confidence(confidence_db: float, low_db: float, high_db: float) -> float:
    """The DF quality (0..100) of a reading from its confidence: 40 at or below `low_db` (the node's default
    quality_min, so every reading is used, weakly), rising linearly to 100 at `high_db`. The self-calibration
    then learns the real noise per quality band, so the mapping only has to be monotone."""
    share = (confidence_db - low_db) / (high_db - low_db)
    return 40.0 + 60.0 * min(max(share, 0.0), 1.0)


class LineFilter:
    """Keeps, per VFO frequency, only lines newer than the last one: the served page repeats a line until the next
    CPI, and a restarted receiver may step back. Counts what it drops. Remembers the latest _VFOS_KEPT frequencies
    (a stream of distinct jittered frequencies would otherwise grow it without bound)."""

    def __init__(self):
        self.last: OrderedDict[float, float] = OrderedDict()
        self.dropped = {"repeated": 0, "backwards": 0}

    def fresh(self, r: KrakenLine) -> bool:
        last = self.last.get(r.frequency_hz)
        if last is not None and r.stamp <= last:
            self.dropped["repeated" if r.stamp == last else "backwards"] += 1
            return False
        self.last[r.frequency_hz] = r.stamp
        self.last.move_to_end(r.frequency_hz)
        if len(self.last) > _VFOS_KEPT:
            self.last.popitem(last=False)
        return True
