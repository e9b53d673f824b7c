"""The one place that knows ROS message types: conversions that work on field names, so live rclpy
messages, messages deserialised from bags by rosbags and dynamic MCAP messages go through the same code."""
from .fields import (
    DfRecord,
    FixRecord,
    df_from_vector3stamped,
    fix_from_navsatfix,
    stamp_seconds,
)

__all__ = ["DfRecord", "FixRecord", "df_from_vector3stamped", "fix_from_navsatfix", "stamp_seconds"]
