"""Message -> engine records, by field name only (no message classes are imported here)."""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

# sensor_msgs/NavSatStatus.STATUS_NO_FIX; STATUS_FIX is 0 and augmented fixes are higher.
STATUS_NO_FIX = -1


class FixRecord(NamedTuple):
    """A NavSatFix's content as Localizer.add_fix takes it."""

    stamp: float
    lat: float
    lon: float
    alt: float
    status: int
    sigma_m: float = math.nan  # horizontal position sigma from position_covariance (NaN: type unknown)


class DfRecord(NamedTuple):
    """A DF record as Localizer.add_bearing takes it (either encoding of docs/interface.md). `sigma_deg`: the
    reading's own sigma, when its encoding gives one (`pose`); NaN: the one its quality gives."""

    stamp: float
    azimuth_deg: float
    quality: float
    frequency_hz: float
    sigma_deg: float = math.nan


def stamp_seconds(header) -> float:
    """header.stamp (sec, nanosec) as float seconds; NaN (refused as a bad stamp) when nanosec is outside
    [0, 1e9), which builtin_interfaces/Time does not allow and which would shift the stamp by up to 4.3 s."""
    nanosec = header.stamp.nanosec
    if not 0 <= nanosec < 1_000_000_000:
        return math.nan
    return header.stamp.sec + nanosec * 1e-9


def seconds_to_stamp(t: float) -> tuple[int, int]:
    """Float seconds to (sec, nanosec), nanosec in [0, 1e9)."""
    ns = int(round(t * 1e9))
    return ns // 1_000_000_000, ns % 1_000_000_000


def _float(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def fix_from_navsatfix(msg) -> FixRecord:
    """sensor_msgs/NavSatFix -> FixRecord."""
    return FixRecord(stamp_seconds(msg.header), _float(msg.latitude), _float(msg.longitude),
                     _float(msg.altitude), int(msg.status.status), horizontal_sigma(msg))


def horizontal_sigma(msg) -> float:
    """sqrt of the mean of the east and north variances of position_covariance (ENU, row-major), or NaN when
    position_covariance_type is COVARIANCE_TYPE_UNKNOWN (0) or the values are not usable."""
    if int(msg.position_covariance_type) <= 0:
        return math.nan
    c = msg.position_covariance
    var = (_float(c[0]) + _float(c[4])) / 2
    return math.sqrt(var) if math.isfinite(var) and var >= 0 else math.nan


def df_from_vector3stamped(msg) -> DfRecord:
    """geometry_msgs/Vector3Stamped DF record -> DfRecord (x azimuth deg, y quality, z frequency Hz)."""
    v = msg.vector
    return DfRecord(stamp_seconds(msg.header), _float(v.x), _float(v.y), _float(v.z))


# A scan's fields (docs/interface.md, "A scan as one message"): azimuth_deg is needed, the others are optional
SCAN_FIELDS = ("azimuth_deg", "quality", "frequency_hz", "sigma_deg")
SCAN_MAX_RECORDS = 100_000  # a cloud claiming more records than this is refused, not allocated
# sensor_msgs/PointField datatypes (INT8 .. FLOAT64) as numpy's
_POINT_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def df_scan(msg) -> list[DfRecord]:
    """sensor_msgs/PointCloud2 DF scan -> one DfRecord per point, every one at the header's stamp: a receiver's
    channels read at one instant (a KrakenSDR's VFOs, a band scan). Fields by name, any numeric PointField type,
    any offsets, either byte order; a missing optional field reads NaN (quality, sigma_deg) or 0 (frequency_hz, the
    default channel). ValueError for a cloud whose layout does not hold its records or has no azimuth_deg."""
    stamp = stamp_seconds(msg.header)
    width, height, step = int(msg.width), int(msg.height), int(msg.point_step)
    n = width * height
    if n == 0:
        return []
    if n > SCAN_MAX_RECORDS or step <= 0 or int(msg.row_step) < width * step:
        raise ValueError(f"a scan of {width} x {height} points of {step} bytes (row {msg.row_step}) is no layout")
    data = np.frombuffer(msg.data, np.uint8)
    starts = (np.arange(height)[:, None] * int(msg.row_step) + np.arange(width)[None, :] * step).ravel()
    if starts[-1] + step > data.size:
        raise ValueError(f"a scan of {n} points of {step} bytes holds only {data.size} bytes")
    order = ">" if msg.is_bigendian else "<"
    fields = {f.name: f for f in msg.fields}
    if "azimuth_deg" not in fields:
        raise ValueError("a DF scan needs an azimuth_deg field")
    columns = {}
    for name in SCAN_FIELDS:
        f = fields.get(name)
        if f is None:
            columns[name] = np.full(n, 0.0 if name == "frequency_hz" else math.nan)
            continue
        dtype = np.dtype(order + _POINT_TYPES[int(f.datatype)]) if int(f.datatype) in _POINT_TYPES else None
        if dtype is None or int(f.count) != 1 or not 0 <= int(f.offset) <= step - dtype.itemsize:
            raise ValueError(f"the scan's field {name} (type {f.datatype}, count {f.count}, offset {f.offset}) "
                             "is not one number inside a point")
        raw = data[starts[:, None] + int(f.offset) + np.arange(dtype.itemsize)[None, :]]
        columns[name] = raw.reshape(-1).view(dtype).astype(float)
    return [DfRecord(stamp, *row) for row in zip(*(columns[k].tolist() for k in SCAN_FIELDS), strict=True)]


class PoseBearing(NamedTuple):
    """A bearing in the `pose` encoding: REP-103 yaw (rad, CCW from east) and its variance (rad^2)."""

    stamp: float
    yaw_rad: float
    variance_rad2: float


# tf2's rule for a usable quaternion: its squared norm within 0.1 of one (tf2::Quaternion's "not properly
# normalized" check). Inside it the quaternion is normalised; outside it, or zero or not finite, there is no yaw.
QUATERNION_NORM2_TOLERANCE = 0.1


def yaw_of(q) -> float:
    """Yaw (rad) of a geometry_msgs/Quaternion, by field name, after normalising it; NaN (the reading refused as
    a bad azimuth or heading) when the quaternion is not finite or its squared norm is off one by more than 0.1."""
    w, x, y, z = (_float(q.w), _float(q.x), _float(q.y), _float(q.z))
    norm2 = w * w + x * x + y * y + z * z
    if not math.isfinite(norm2) or abs(norm2 - 1.0) > QUATERNION_NORM2_TOLERANCE:
        return math.nan
    return math.atan2(2.0 * (w * z + x * y) / norm2, 1.0 - 2.0 * (y * y + z * z) / norm2)


def sigma_deg_of_variance(variance_rad2: float) -> float:
    """A pose's yaw variance (rad^2) as a reading's sigma (deg) by add_bearing's rule: NaN or 0 (the ROS
    convention for a covariance not filled in) give NaN, the configured sigma; a negative or infinite variance
    gives a negative or infinite sigma, which add_bearing refuses as `bad_sigma`."""
    if math.isnan(variance_rad2) or variance_rad2 == 0.0:
        return math.nan
    return math.copysign(math.degrees(math.sqrt(abs(variance_rad2))), variance_rad2)


class HeadingRecord(NamedTuple):
    """An IMU's heading as Localizer.add_heading takes it: REP-103 yaw (rad, counter-clockwise from east) and its
    variance (rad^2; NaN: not known)."""

    stamp: float
    yaw_rad: float
    variance_rad2: float = math.nan


def heading_from_imu(msg) -> HeadingRecord:
    """sensor_msgs/Imu -> HeadingRecord: the yaw of its orientation (NaN when the orientation is unknown, which
    REP-145 marks with orientation_covariance[0] = -1) and the yaw's variance, the covariance's last element (NaN
    when it is 0, REP-145's "not known")."""
    cov = msg.orientation_covariance
    known = _float(cov[0]) != -1.0
    variance = _float(cov[8])
    return HeadingRecord(stamp_seconds(msg.header), yaw_of(msg.orientation) if known else math.nan,
                         variance if known and variance > 0 else math.nan)


def bearing_from_pose(msg) -> PoseBearing:
    """geometry_msgs/PoseWithCovarianceStamped bearing -> PoseBearing (variance from covariance[35])."""
    return PoseBearing(stamp_seconds(msg.header), yaw_of(msg.pose.pose.orientation), _float(msg.pose.covariance[35]))


def df_from_pose(msg) -> DfRecord:
    """A `pose` bearing (bearing_from_pose) as a DF record: its yaw as an azimuth (deg clockwise from north), its
    variance as the reading's sigma (sigma_deg_of_variance), no quality, no frequency. The same arithmetic as
    Localizer.add_bearing_enu, so a live pose and a replayed one give one answer."""
    p = bearing_from_pose(msg)
    azimuth = 90.0 - math.degrees(p.yaw_rad) if math.isfinite(p.yaw_rad) else p.yaw_rad
    return DfRecord(p.stamp, azimuth, math.nan, math.nan, sigma_deg_of_variance(p.variance_rad2))


def df_record(msg, encoding: str) -> DfRecord:
    """A bearing message in `bearing_encoding` (`df_record`: Vector3Stamped; `pose`: PoseWithCovarianceStamped) as
    one DfRecord, so the node hands either to the engine by one call."""
    return df_from_vector3stamped(msg) if encoding == "df_record" else df_from_pose(msg)


def estimate_from_pose(msg) -> tuple[float, float, float, list[list[float]]]:
    """emitter/pose -> (stamp, east, north, 2x2 covariance)."""
    c = msg.pose.covariance
    return (stamp_seconds(msg.header), msg.pose.pose.position.x, msg.pose.pose.position.y,
            [[c[0], c[1]], [c[6], c[7]]])


def diagnostics_values(msg) -> dict[str, dict[str, str]]:
    """DiagnosticArray -> {status name: {key: value, 'level': .., 'message': ..}}."""
    out = {}
    for st in msg.status:
        values = {kv.key: kv.value for kv in st.values}
        level = st.level if isinstance(st.level, int) else int.from_bytes(bytes(st.level), "little")
        values.update(level=str(level), message=st.message)
        out[st.name] = values
    return out
