"""LocalizerConfig: every parameter of the engine, declared once (type, default, range or choices, meaning, whether
it is fixed at start), with the AFSA paper's defaults. The validation, the node's ROS parameter descriptors and the
README's parameter table are all derived from these declarations (`parameter_specs()`).

The same names are the node's ROS parameters (a seed filter's settings as `<filter>.<name>`), so a params
YAML file and a Python notebook describe a run the same way.
"""
from __future__ import annotations

import math
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass, replace
from typing import Any

from aoa_localizer.core.spec import ConfigError, IncompleteGroup, ParameterSpec, choice, param, unknown_names
from aoa_localizer.filters import REGISTRY
from aoa_localizer.filters.algorithm import GroupAccess
from aoa_localizer.filters.registry import default_groups, groups

# sqrt(3.801e-4 rad^2), the AFSA paper's bearing noise, in degrees.
PAPER_BEARING_SIGMA_DEG = math.degrees(math.sqrt(3.801e-4))

ALGORITHMS = tuple(REGISTRY)
GROUPS = groups()
# Parameters set together or not at all (a place needs both coordinates, a prior its place and its spread)
SET_TOGETHER = (("prior_east", "prior_north", "prior_sigma_m"), ("datum_lat", "datum_lon"))
MAX_PARTICLES = 100_000
FREQUENCY_MAX_HZ = 1e12  # the highest frequency a DF record may carry (above: `bad_frequency`)


@dataclass(frozen=True)
class LocalizerConfig(GroupAccess):
    """All engine parameters. Defaults are the AFSA paper's where it gives one (see docs/design.md)."""

    algorithm: str = choice("afsa", ALGORITHMS, ", ".join(f"`{a.name}` ({a.label})" for a in REGISTRY.values())
                            + "; docs/benchmarks.md says how each does on the emitter")
    num_particles: int = param(
        100,
        "number of particles N (the cost per update grows with N: docs/benchmarks.md; "
        "live, /diagnostics warns when the callbacks no longer fit the input rate)",
        low=2,
        high=MAX_PARTICLES,
    )
    seed: int | None = param(None, "filter seed; unset: random. The same seed reproduces a run", kind=int, low=0)
    # Bearing noise model: one sigma for every reading, or a sigma that grows linearly as quality falls.
    bearing_sigma_deg: float = param(
        PAPER_BEARING_SIGMA_DEG,
        "reading sigma (deg; the paper's 3.801e-4 rad^2) for `sigma_model: constant`",
        low=0.0,
        low_open=True,
        high=90.0,
    )
    sigma_model: str = choice(
        "constant",
        ("constant", "quality"),
        "`constant`, or `quality`: sigma linear from `sigma_q40_deg` at Q = 40 to `sigma_q100_deg` at Q = 100",
    )
    sigma_q100_deg: float = param(
        1.0, "reading sigma at quality 100 (deg), `sigma_model: quality`", low=0.0, low_open=True, high=90.0
    )
    sigma_q40_deg: float = param(
        8.0, "reading sigma at quality 40 (deg), `sigma_model: quality`", low=0.0, low_open=True, high=90.0
    )
    likelihood: str = choice(
        "mixture",
        ("mixture", "gaussian"),
        "`mixture`: Gaussian + uniform outliers with `outlier_prob`; `gaussian`: the paper's",
    )
    outlier_prob: float = param(
        0.05,
        "share of wild bearings the mixture likelihood allows for (the starting guess when `calibrate_noise`)",
        low=0.0,
        high=1.0,
        high_open=True,
    )
    process_noise_m: float = param(
        1.0, "random walk per step (m, paper eq. 17) for `sir` and `afsa.variant: paper`", low=0.0, high=1e4
    )
    # Bearing pre-processing (paper sec. 3.2) and what one observation point is.
    quality_min: float = param(40.0, "readings with a lower DF quality are dropped", low=0.0, high=100.0)
    point_weighting: str = choice(
        "inverse_variance",
        ("paper", "inverse_variance", "equal"),
        "combination of a point's readings: `inverse_variance` (1/sigma^2, the best with "
        "calibrated sigmas), `paper` (eqs. 19-21) or `equal`",
    )
    obs_max_duration_s: float = param(2.0, "longest span of one observation point (s)", low=1e-3, high=3600.0)
    obs_max_distance_m: float = param(10.0, "longest distance covered by one observation point (m)", low=0.0, high=1e5)
    obs_max_range_share: float = param(
        0.05, "longest distance covered by one observation point as a share of its range to the emitter's estimate, "
        "once that is determined (a pass close by sweeps the bearing across a point; 0: off)", low=0.0, high=1.0
    )
    obs_max_readings: int = param(50, "most readings in one observation point", low=1, high=100_000)
    df_correlation: float = param(
        0.0, "correlation of the readings at one point (1: ten readings count as one)", low=0.0, high=1.0
    )
    point_gate_sigma: float = param(
        4.0, "wild-reading gate inside a point, in sigmas from its median (0: off)", low=0.0, high=100.0
    )
    # Start: global search of the robust posterior (or the paper's triangulation), unless a prior is given.
    init_method: str = choice(
        "global",
        ("global", "triangulation"),
        "`global`: start from the best mode of a "
        "global search of the robust posterior; `triangulation`: the paper's crossing pairs",
    )
    init_bearings: int = param(3, "observation points before a start is tried (an estimate comes as soon as the "
                               "bearings cross; the end of data tries with 2)", low=2, high=100_000)
    init_min_crossing_deg: float = param(
        10.0,
        "steepest crossing (deg) among the bearings the start mode explains",
        low=0.0,
        high=90.0,
        low_open=True,
        high_open=True,
    )
    init_min_support: float = param(
        0.6, "`triangulation` only: share of points that must agree with a crossing",
            low=0.0, high=1.0
    )
    init_max_points: int = param(500, "points kept while waiting for geometry (at least `init_bearings`)", low=2,
                                 high=100_000)
    prior_east: float | None = param(
        None,
        "Gaussian prior mean east (m, map); set with `prior_north` and `prior_sigma_m`, it replaces the start search",
        kind=float,
        low=-2e7, high=2e7,
    )
    prior_north: float | None = param(None, "Gaussian prior mean north (m, map)", kind=float, low=-2e7, high=2e7)
    prior_sigma_m: float | None = param(None, "Gaussian prior sigma (m)", kind=float, low=0.0, low_open=True, high=2e7)
    # Frames and GPS pairing.
    datum_lat: float | None = param(
        None,
        "latitude of the map origin (deg); unset: the first valid fix, once the next fix confirms it",
        kind=float,
        low=-90.0,
        high=90.0,
    )
    datum_lon: float | None = param(
        None, "longitude of the map origin (deg), set with `datum_lat`", kind=float, low=-180.0, high=180.0
    )
    datum_alt: float | None = param(None, "altitude of the map origin (m); unset: the first valid fix's", kind=float,
                                    low=-1000.0, high=20_000.0)
    gps_max_gap_s: float = param(
        2.0, "longest fix gap a bearing may be interpolated across (s)", low=1e-3, low_open=True, high=86_400.0
    )
    max_stamp_jump_s: float = param(
        300.0,
        "a stamp this far ahead of its stream is refused, not adopted; a clock "
        "step is followed after 3 agreeing stamps (s)",
        low=1.0,
        low_open=True,
        high=86_400.0,
    )
    df_time_offset_s: float = param(
        0.0,
        "added to every DF stamp to put it on the GPS clock (a receiver that "
        "stamps 0.5 s late: -0.5); /diagnostics suggests one when the bearings show it",
        low=-3600.0, high=3600.0,
    )
    # Several emitters at once, keyed by the DF record's frequency (docs/design.md, "Channels").
    channel_tolerance_hz: float = param(
        5000.0, "a DF record within this of a channel's frequency belongs to it (Hz); records with frequency 0 or "
        "NaN share the default channel", low=0.0, low_open=True,
        high=1e9,
    )
    max_channels: int = param(
        64, "most frequency channels tracked at once; a record that would open one more is refused "
        "(`channel_limit`)", low=1, high=10_000,
    )
    max_emitters_per_channel: int = param(
        3, "most transmitters counted on one channel's frequency (co-channel: they take turns, push-to-talk); the "
        "count is said on each estimate (`transmitter_count`, `transmitters`); 1: never counted", low=1, high=5,
    )
    channel_timeout_s: float = param(
        300.0, "a frequency channel silent this long (DF time) is retired, its last estimate kept (s; 0: never)",
        low=0.0,
        high=1e6,
    )
    frequency_band_hz: tuple = param(
        (), "[low, high] (Hz): take only DF records with low <= frequency < high, so several nodes can share a "
        "spectrum; the others, and records without a frequency, are counted as `other_band`, not refused. Empty: "
        "every record", kind=list, low=0, high=2, read_only=True,
    )
    # What a DF azimuth is measured from (docs/design.md, "Bearing reference").
    bearing_reference: str = choice(
        "true_north",
        ("true_north", "magnetic_north", "vehicle"),
        "what a DF azimuth is measured from, clockwise: `true_north`, `magnetic_north` (with "
        "`magnetic_declination_deg`) or `vehicle` (the vehicle's forward axis, with `mount_offset_deg` and "
        "the heading from `heading_source`)",
        read_only=True,
    )
    magnetic_declination_deg: float = param(
        0.0, "magnetic declination, east positive (as navsat_transform has it): true = magnetic + declination",
        low=-180.0, high=180.0,
    )
    mount_offset_deg: float = param(
        0.0, "the DF array's zero, clockwise from the vehicle's forward axis (deg), `bearing_reference: vehicle`",
        low=-360.0, high=360.0,
    )
    offset_sigma_deg: float = param(
        -1.0, "how far the configured reference's zero may still be off (deg, one standard deviation), "
        "marginalised into the estimate, so the ellipse carries it where the bearings cannot tell an offset from a "
        "place (a straight drive); negative: by "
        "`bearing_reference` (0 for true_north, 2 for magnetic_north, 3 for vehicle with `mount_offset_deg` set, "
        "10 for vehicle without); 0: the offset is known exactly", low=-1.0, high=90.0,
    )
    heading_source: str = choice(
        "track", ("track", "imu"),
        "the vehicle's heading for `bearing_reference: vehicle`: `track` (course over ground from the GPS fixes) "
        "or `imu` (REP-103 yaw of sensor_msgs/Imu on heading/imu, `Localizer.add_heading`)",
        read_only=True,
    )
    heading_min_speed_mps: float = param(
        1.0, "`heading_source: track`: slower than this the course is not trusted and the last good heading is "
        "held (m/s)", low=0.0, low_open=True,
        high=100.0,
    )
    heading_max_sigma_deg: float = param(
        10.0, "`heading_source: track`: the most uncertain course used (deg); its sigma, from the GPS fixes' "
        "jitter, is added to the bearings' (a longer window is tried first: x2, x4)", low=0.0, low_open=True,
        high=90.0,
    )
    heading_hold_s: float = param(
        60.0, "longest a heading is held (stopped vehicle, IMU gap) before readings are refused as "
        "`heading_unknown` (s)", low=0.0,
        high=86_400.0,
    )
    heading_window_s: float = param(
        3.0, "`heading_source: track`: span of fixes the course is fitted over, centred on the reading (s)",
        low=0.1, low_open=True,
        high=600.0,
    )
    gps_sigma_m: float = param(
        0.0,
        "GPS position noise (m), added to each bearing's variance by range; 0: each "
        "fix's own position_covariance (when its type is not unknown)",
        low=0.0,
        high=1e4,
    )
    bearing_encoding: str = choice(
        "df_record",
        ("df_record", "pose"),
        "`df_record` (Vector3Stamped: azimuth deg, "
        "quality) or `pose` (PoseWithCovarianceStamped yaw; `Localizer.add_bearing_enu` "
        "in Python)",
        read_only=True,
    )
    # Particle-filter skeleton.
    resampling: str = choice("systematic", ("systematic", "stratified", "residual", "multinomial"), "resampling scheme")
    ess_threshold: float = param(
        0.5, "resample when the effective sample size falls below this share of N", low=0.0, high=1.0
    )
    move_sweeps: int = param(3, "sweeps of a filter's moves after each resampling (the mcmc variants; AFSA: "
                             "`afsa.max_iterations`)", low=1, high=1000)
    history_points: int = param(300, "observation points the MCMC moves' posterior keeps", low=1, high=100_000)
    # Robustness (docs/design.md "Never confidently wrong"): noise self-calibration, global-mode safety,
    # emitter-moved test.
    end_of_data_model: str = choice(
        "survey",
        ("survey", "filter"),
        "at `finish()` (offline, the API): `survey` locates the channels whose every bearing came from a fixed "
        "station, or from stops that show a steady site part, by the survey model `locate` runs, the same answer; "
        "`filter`: the particle filter's end-of-data check for every channel",
    )
    receiver_class: str = choice(
        "unknown",
        ("unknown", "handheld", "electronic", "mast", "indoor"),
        "what the receiver is, for the survey model's prior on its error (docs/interface.md, \"Survey model\")",
    )
    calibrate_noise: bool = param(
        True,
        "learn the receiver's sigma per quality band and the outlier rate from the "
        "data (the configured model is the starting guess)",
    )
    noise: str = choice(
        "unknown",
        ("unknown", "fixed"),
        "`unknown`: the receiver's noise scale and wild share are latent (a weakly informative prior over 0.5-45 "
        "deg centred on the configured sigma, marginalised with the position) until the readings calibrate them; "
        "`fixed`: the configured sigma is taken as known (then calibrated when `calibrate_noise`)",
    )
    learn_offset: bool = param(
        True,
        "learn a constant bearing offset (a mount offset, a forgotten declination) where the data determine it, "
        "at the noise calibrations, and report it; the evidence needed follows `bearing_reference`",
    )
    global_safety: bool = param(
        True,
        "health test, global searches, independence MH moves, re-starts and the "
        "emitter-moved test (false: the filters alone)",
    )
    scheduling: str = choice(
        "auto",
        ("auto", "realtime", "reproducible"),
        "`realtime`: the global checks' and start searches' noise fits and searches run in a worker process (their "
        "result applied at the emitter's next point) and a resampling's move sweeps are owed, made between "
        "messages (the node's idle time) or one per following point, so no step blocks for long; `reproducible`: "
        "in the calls, made in turns, one per following point (as long as a cost model of the work, never the "
        "clock, lets under a few ms), so a seed repeats a run exactly; `auto`: realtime in the node, "
        "reproducible offline and from Python",
        read_only=True,
    )
    health_window: int = param(
        10, "recent points whose outlier share is tested against the outlier rate", low=3, high=1000
    )
    health_p_value: float = param(
        1e-3,
        "binomial tail below which the recent outlier share raises the alarm",
        low=0.0,
        high=1.0,
        low_open=True,
        high_open=True,
    )
    restart_log_odds: float = param(
        10.0,
        "re-start from a global mode whose log posterior beats the cloud's best particle by this many nats",
        low=0.0,
        low_open=True,
        high=1e4,
    )
    moved_min_points: int = param(
        8, "disagreeing recent points needed before the emitter-moved test", low=3, high=100_000
    )
    moved_log_odds: float = param(
        20.0,
        "log likelihood ratio (nats) both old and recent points must show to declare the emitter moved",
        low=0.0,
        low_open=True,
        high=1e4,
    )
    # Moving transmitters (issue 68, engine/inference/motion.py)
    motion_model: str = choice(
        "auto",
        ("auto", "static"),
        "`auto`: beside each channel's filter a static and a moving model weigh its points, and where motion is "
        "probable the estimate follows the moving transmitter (`motion`, `motion_probability`, `velocity`); "
        "`static`: every transmitter stands (no watch; nor without `global_safety`)",
    )
    max_transmitter_speed_mps: float = param(
        30.0, "the moving model's top speed scale (m/s): its prior on a transmitter's speed is log-uniform from "
        "0.3 m/s up to this (a walker 1-2, a car 10-20, a drone 5-15)", low=0.0, low_open=True, high=1000.0,
    )
    # Each algorithm's settings group, (name, settings) in GROUPS order, read as `cfg.<name>` (filters/registry.py)
    groups: tuple[tuple[str, Any], ...] = field(default_factory=default_groups)

    def __post_init__(self):
        if isinstance(self.frequency_band_hz, list):  # as ROS and YAML give it; a tuple keeps the config hashable
            object.__setattr__(self, "frequency_band_hz", tuple(self.frequency_band_hz))
        _validate(self)

    def in_band(self, frequency_hz: float) -> bool:
        """Whether this configuration takes a DF record of `frequency_hz` (NaN or 0: none given)."""
        if not self.frequency_band_hz:
            return True
        low, high = self.frequency_band_hz
        return low <= frequency_hz < high  # half-open: adjacent bands share no frequency; False for NaN

    @property
    def has_prior(self) -> bool:
        return self.prior_sigma_m is not None

    @property
    def has_datum(self) -> bool:
        return self.datum_lat is not None

    def with_changes(self, **changes) -> LocalizerConfig:
        """A copy with some fields changed (flat `afsa.x` keys, or a whole group as a dict or its settings), validated
        again."""
        for group in GROUPS:
            if group in changes:
                changes.update({f"{group}.{k}": v for k, v in _as_dict(changes.pop(group)).items()})
        return LocalizerConfig.from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict:
        """Flat dict with `group.<name>` keys (afsa., espf., gfapf.): the node's parameter names."""
        d = asdict(self)
        for group, values in d.pop("groups"):
            d.update({f"{group}.{k}": v for k, v in values.items()})
        return d

    @classmethod
    def from_dict(cls, values: dict) -> LocalizerConfig:
        """Build from a flat or nested dict (a group as a dict or its settings); unknown keys are refused with their
        names."""
        values = dict(values)
        groups, unknown = {}, []
        for group, group_cls in GROUPS.items():
            nested = values.pop(group, None) or {}
            given = _as_dict(nested)
            for key in [k for k in values if k.startswith(f"{group}.")]:
                given[key[len(group) + 1 :]] = values.pop(key)
            known = {f.name for f in fields(group_cls)}
            unknown += [f"{group}.{k}" for k in sorted(set(given) - known)]
            groups[group] = {k: v for k, v in given.items() if k in known}
        unknown = sorted(set(values) - {f.name for f in fields(cls) if f.name != "groups"}) + unknown
        if unknown:
            raise ConfigError(unknown_names(unknown, [p.name for p in parameter_specs()]))
        built = tuple((group, replace(GROUPS[group](), **given)) for group, given in groups.items())
        return cls(**values, groups=built)


def _as_dict(group) -> dict:
    """A settings group given as a dict or as its settings dataclass, as a dict."""
    return asdict(group) if is_dataclass(group) and not isinstance(group, type) else dict(group)


def _check(ok: bool, message: str):
    if not ok:
        raise ConfigError(message)


def _validate(cfg: LocalizerConfig):
    """Every declared constraint, then what ties parameters together."""
    for f in fields(cfg):
        if f.name != "groups":
            f.metadata["spec"].check(f.name, getattr(cfg, f.name))
    _check([name for name, _ in cfg.groups] == list(GROUPS), f"groups must be {', '.join(GROUPS)}, in that order")
    for name, group in cfg.groups:
        _check(isinstance(group, GROUPS[name]), f"{name} must be a {GROUPS[name].__name__}")
        for g in fields(group):
            g.metadata["spec"].check(f"{name}.{g.name}", getattr(group, g.name))
    band = cfg.frequency_band_hz
    _check(not band or (len(band) == 2 and 0 <= band[0] < band[1] <= FREQUENCY_MAX_HZ),
           f"frequency_band_hz must be empty or [low, high] with 0 <= low < high <= {FREQUENCY_MAX_HZ:g}, got "
           f"{list(band)!r}")
    _check(
        cfg.init_max_points >= cfg.init_bearings,
        f"init_max_points must be >= init_bearings ({cfg.init_bearings}), got {cfg.init_max_points!r}",
    )
    for group in SET_TOGETHER:
        unset = [name for name in group if getattr(cfg, name) is None]
        if 0 < len(unset) < len(group):
            raise IncompleteGroup(group, unset)


def parameter_specs() -> list[ParameterSpec]:
    """Every engine parameter in declaration order (group settings last, as `<group>.<name>`)."""
    out = []
    for f in fields(LocalizerConfig):
        if f.name != "groups":
            default = None if f.default is MISSING else f.default
            out.append(ParameterSpec(f.name, list(default) if isinstance(default, tuple) else default,
                                     f.metadata["spec"]))
    for name, cls in GROUPS.items():
        out += [ParameterSpec(f"{name}.{g.name}", g.default, g.metadata["spec"]) for g in fields(cls)]
    return out
