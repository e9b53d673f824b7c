"""Message classes from their ROS type names ("pkg/msg/Name"), without rosidl_runtime_py."""
from __future__ import annotations

import importlib


def message_class(type_name: str):
    """The rclpy class of a message type name, or None if its package is not installed."""
    try:
        pkg, kind, name = type_name.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ValueError, ImportError, AttributeError):
        return None
