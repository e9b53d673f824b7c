"""The node's own parameters (the ROS shell's, not engine settings), declared like the engine's; no rclpy here, so
the README's tables can be written without ROS."""
from aoa_localizer.engine.config import ParameterSpec, Spec

NODE_PARAMS = [
    ParameterSpec("input_queue_depth", 200, Spec("subscription queue depth for gps/fix and df/bearing", int,
                                                 low=1, high=100_000, read_only=True)),
    ParameterSpec("marker_rays", 20, Spec("bearing rays drawn in emitter/markers (the latest observation points)",
                                          int, low=0, high=10_000)),
    ParameterSpec("diagnostics_period_s", 1.0, Spec("period of /diagnostics (s)", float, low=0.01, high=3600.0,
                                                    read_only=True)),
]
