"""The node's own parameters (the ROS shell's, not engine settings), declared like the engine's; no rclpy here, so
the README's tables can be written without ROS."""
from aoa_localizer.core.spec import ParameterSpec, Spec

NODE_PARAMS = [
    ParameterSpec("input_queue_depth", 200, Spec("subscription queue depth for gps/fix, df/bearing and df/scan", int,
                                                 low=1, high=100_000, read_only=True)),
    ParameterSpec("input_reliability", "best_effort", Spec(
        "QoS reliability of the gps/fix, df/bearing and df/scan subscriptions: `best_effort` (sensor data: reliable "
        "and best-effort publishers both connect, a message can be lost under load) or `reliable` (lost packets are "
        "resent, but only reliable publishers connect, and a publisher's KEEP_LAST history still drops under load)",
        str, choices=("best_effort", "reliable"), read_only=True)),
    ParameterSpec("map_frame", "map", Spec("frame_id of emitter/pose, emitter/particles, emitter/markers and "
                                           "vehicle/path: ENU metres at the datum (emitter/datum)", str,
                                           read_only=True)),
    ParameterSpec("emitter_frame", "emitter", Spec("frame_id of emitter/fix (the emitter's own position)", str,
                                                   read_only=True)),
    ParameterSpec("path_length", 1000, Spec("GPS fixes kept in vehicle/path (0: the path is not published)", int,
                                            low=0, high=1_000_000)),
    ParameterSpec("marker_rays", 20, Spec("bearing rays drawn in emitter/markers (the latest observation points)",
                                          int, low=0, high=10_000)),
    ParameterSpec("goal_radius_m", 500.0, Spec(
        "emitter/next_goal is the place within this distance of the vehicle (the first moving station) whose next "
        "bearing is expected to shrink the posterior most (m)", float, low=1.0, high=100_000.0)),
    ParameterSpec("diagnostics_period_s", 1.0, Spec("period of /diagnostics and vehicle/path (s)", float, low=0.01,
                                                    high=3600.0, read_only=True)),
    ParameterSpec("stale_after_s", 5.0, Spec("/diagnostics warns when no DF reading or no valid GPS fix arrived for "
                                             "this long (s)", float, low=0.0, low_open=True, high=86_400.0)),
    ParameterSpec("shed_overload", True, Spec(
        "when the engine's work leaves the input messages waiting 0.25 s (median) before the node takes them (the "
        "engine filling half a diagnostics period), keep each DF record with a probability halved each such period "
        "(down to 1/16) and doubled back once they wait under 0.05 s with the engine filling under 30 %; "
        "the records shed are counted (records_shed) and said under `overload`; false: none are shed (a backlog then "
        "grows in the input queue, or it drops whole messages)", bool)),
    ParameterSpec("stations", [], Spec(
        "DF stations whose inputs are fused: each NAME subscribes NAME/gps/fix, NAME/df/bearing, NAME/df/scan (and "
        "NAME/heading/imu) and publishes NAME/vehicle/path; empty: one station on gps/fix, df/bearing and df/scan",
        list, items=str,
        read_only=True)),
    ParameterSpec("fixed_stations", [], Spec(
        "the stations (of `stations`) that do not move: their position is `<NAME>.position` if set, else their "
        "newest fix; a bearing is placed there at any time", list, items=str, read_only=True)),
    ParameterSpec("hardware_id", "df_receiver", Spec("hardware_id of the /diagnostics status (the DF receiver's name "
                                                     "or serial)", str)),
    ParameterSpec("cot_url", "", Spec(
        "where each channel's estimate goes as a Cursor-on-Target event for TAK (ATAK, WinTAK, iTAK), in pytak's "
        "convention: udp://239.2.3.1:6969 (multicast), udp://HOST:PORT, tcp://HOST:PORT; empty: none (needs "
        "pip install 'aoa_localizer[tak]')", str, read_only=True, empty=True)),
    ParameterSpec("cot_period_s", 1.0, Spec("a channel's CoT event is sent at most this often, while its estimate "
                                            "changes (s)", float, low=0.0, high=3600.0, read_only=True)),
    ParameterSpec("cot_stale_s", 120.0, Spec("a CoT event's stale time after it is sent: TAK greys the emitter out "
                                             "when no newer one came (s)", float, low=1.0, high=86_400.0,
                                             read_only=True)),
]

# Declared once per fixed station, as `<NAME>.position` (the README shows it under this name).
STATION_POSITION = ParameterSpec("<NAME>.position", [], Spec(
    "a fixed station's position [lat, lon] or [lat, lon, alt] (deg, deg, m); empty: from its fixes", list, low=0,
    high=3, read_only=True))
