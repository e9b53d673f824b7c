"""Engine records -> messages, by field name: the caller passes the message classes it uses
(rosbags' typestore classes to write bags, rclpy's to publish), so one function serves both."""
from __future__ import annotations

from types import SimpleNamespace

from .fields import seconds_to_stamp


def rosbags_types(typestore) -> SimpleNamespace:
    """The message classes of a rosbags typestore under short names."""
    t = typestore.types
    return SimpleNamespace(
        Time=t["builtin_interfaces/msg/Time"], Header=t["std_msgs/msg/Header"],
        NavSatFix=t["sensor_msgs/msg/NavSatFix"], NavSatStatus=t["sensor_msgs/msg/NavSatStatus"],
        Vector3Stamped=t["geometry_msgs/msg/Vector3Stamped"], Vector3=t["geometry_msgs/msg/Vector3"],
        PointStamped=t["geometry_msgs/msg/PointStamped"], Point=t["geometry_msgs/msg/Point"],
    )


def header(T, stamp: float, frame_id: str):
    sec, nanosec = seconds_to_stamp(stamp)
    return T.Header(stamp=T.Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def navsatfix(T, stamp: float, lat: float, lon: float, alt: float, status: int = 0,
              frame_id: str = "gps", covariance=None, covariance_type: int = 0):
    """sensor_msgs/NavSatFix (service 1 = GPS)."""
    import numpy as np

    cov = np.zeros(9) if covariance is None else np.asarray(covariance, float).reshape(9)
    return T.NavSatFix(header=header(T, stamp, frame_id), status=T.NavSatStatus(status=status, service=1),
                       latitude=lat, longitude=lon, altitude=alt, position_covariance=cov,
                       position_covariance_type=covariance_type)


def df_record(T, stamp: float, azimuth_deg: float, quality: float, frequency_hz: float = 0.0,
              frame_id: str = "df_antenna"):
    """geometry_msgs/Vector3Stamped DF record."""
    return T.Vector3Stamped(header=header(T, stamp, frame_id),
                            vector=T.Vector3(x=azimuth_deg, y=quality, z=frequency_hz))


def point_stamped(T, stamp: float, x: float, y: float, z: float = 0.0, frame_id: str = "map"):
    """geometry_msgs/PointStamped."""
    return T.PointStamped(header=header(T, stamp, frame_id), point=T.Point(x=x, y=y, z=z))
