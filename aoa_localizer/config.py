"""LocalizerConfig: every parameter of the engine, with the AFSA paper's defaults, validated with clear messages.

The same names are the node's ROS parameters (fish-school settings as `afsa.<name>`), so a params
YAML file and a Python notebook describe a run the same way.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, replace
from numbers import Integral, Real

# sqrt(3.801e-4 rad^2), the AFSA paper's bearing noise, in degrees.
PAPER_BEARING_SIGMA_DEG = math.degrees(math.sqrt(3.801e-4))

ALGORITHMS = ("afsa", "sir", "espf", "gfapf", "upfde", "upf", "pfde", "agapf")
RESAMPLING = ("systematic", "stratified", "residual", "multinomial")
LIKELIHOODS = ("mixture", "gaussian")
SIGMA_MODELS = ("constant", "quality")
POINT_WEIGHTINGS = ("paper", "inverse_variance", "equal")
AFSA_VARIANTS = ("mcmc", "paper")
BEARING_ENCODINGS = ("df_record", "pose")
INIT_METHODS = ("global", "triangulation")
MAX_PARTICLES = 100_000


class ConfigError(ValueError):
    """A parameter value the engine refuses (never clamped silently)."""


@dataclass(frozen=True)
class AfsaConfig:
    """Fish-school settings (AFSA paper sec. 2.2 and 5). `variant` picks the paper's greedy school or ours."""

    variant: str = "mcmc"
    visual: float = 1.0
    step: float = 0.3
    crowd: float = 0.618
    try_number: int = 50
    max_iterations: int = 5
    tolerance: float = 1e-3


@dataclass(frozen=True)
class EspfConfig:
    """ESPF settings: the SBX distribution index lambda (any non-negative real in the paper; docs/seed_tables.md)."""

    sbx_lambda: float = 2.0


@dataclass(frozen=True)
class GfapfConfig:
    """GFA-PF settings (paper sec. 2): attraction M, rotation factor maximum, D iterations, the dead zone of the
    attraction and the range of the repulsion. `scale`: `absolute` reads the two distances in state units (the
    paper's 1-D models); `spread` in standard deviations of the cloud (the emitter problem, any scale)."""

    attraction: float = 0.0618
    rotation_max: float = 0.3
    iterations: int = 8
    attract_min: float = 0.5
    repel_max: float = 0.2
    scale: str = "spread"


@dataclass(frozen=True)
class DeConfig:
    """Differential evolution of UPF-DE and PF-DE: V = F1 X_r1 + F2 (X_r2 - X_r3), binomial crossover Cr, G generations."""

    f1: float = 1.0
    f2: float = 0.9
    cr: float = 0.6
    generations: int = 20


@dataclass(frozen=True)
class AgapfConfig:
    """AGA-PF's adaptive crossover and mutation probabilities (eqs. 18-19)."""

    pc1: float = 0.95
    pc2: float = 0.5
    pm1: float = 0.07
    pm2: float = 0.001
    a: float = 9.9034


@dataclass(frozen=True)
class LocalizerConfig:
    """All engine parameters. Defaults are the AFSA paper's where it gives one (see docs/design.md)."""

    algorithm: str = "afsa"
    num_particles: int = 100
    seed: int | None = None
    # Bearing noise model: one sigma for every reading, or a sigma that grows linearly as quality falls.
    bearing_sigma_deg: float = PAPER_BEARING_SIGMA_DEG
    sigma_model: str = "constant"
    sigma_q100_deg: float = 1.0
    sigma_q40_deg: float = 8.0
    likelihood: str = "mixture"
    outlier_prob: float = 0.05
    process_noise_m: float = 1.0
    # Bearing pre-processing (paper sec. 3.2) and what one observation point is.
    quality_min: float = 40.0
    point_weighting: str = "inverse_variance"
    obs_max_duration_s: float = 2.0
    obs_max_distance_m: float = 10.0
    obs_max_readings: int = 50
    df_correlation: float = 0.0
    point_gate_sigma: float = 4.0
    # Start: global search of the robust posterior (or the paper's triangulation), unless a prior is given.
    init_method: str = "global"
    init_bearings: int = 10
    init_min_crossing_deg: float = 10.0
    init_min_support: float = 0.6
    init_max_points: int = 500
    prior_east: float | None = None
    prior_north: float | None = None
    prior_sigma_m: float | None = None
    # Frames and GPS pairing.
    datum_lat: float | None = None
    datum_lon: float | None = None
    datum_alt: float | None = None
    gps_max_gap_s: float = 2.0
    max_stamp_jump_s: float = 300.0
    df_time_offset_s: float = 0.0
    gps_sigma_m: float = 0.0
    bearing_encoding: str = "df_record"
    # Particle-filter skeleton.
    resampling: str = "systematic"
    ess_threshold: float = 0.5
    history_points: int = 300
    # Robustness (docs/design.md "Never confidently wrong"): noise self-calibration, global-mode safety,
    # emitter-moved test.
    calibrate_noise: bool = True
    global_safety: bool = True
    health_window: int = 10
    health_p_value: float = 1e-3
    restart_log_odds: float = 10.0
    moved_min_points: int = 8
    moved_log_odds: float = 20.0
    afsa: AfsaConfig = field(default_factory=AfsaConfig)
    espf: EspfConfig = field(default_factory=EspfConfig)
    gfapf: GfapfConfig = field(default_factory=GfapfConfig)
    de: DeConfig = field(default_factory=DeConfig)
    agapf: AgapfConfig = field(default_factory=AgapfConfig)

    def __post_init__(self):
        _validate(self)

    @property
    def has_prior(self) -> bool:
        return self.prior_sigma_m is not None

    @property
    def has_datum(self) -> bool:
        return self.datum_lat is not None

    def with_changes(self, **changes) -> "LocalizerConfig":
        """A copy with some fields changed (flat `afsa.x` keys allowed), validated again."""
        return LocalizerConfig.from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict:
        """Flat dict with `group.<name>` keys (afsa., espf., gfapf.): the node's parameter names."""
        d = asdict(self)
        for group in GROUPS:
            d.update({f"{group}.{k}": v for k, v in d.pop(group).items()})
        return d

    @classmethod
    def from_dict(cls, values: dict) -> "LocalizerConfig":
        """Build from a flat or nested dict; unknown keys are refused with their names."""
        values = dict(values)
        groups, unknown = {}, []
        for group, group_cls in GROUPS.items():
            given = dict(values.pop(group, None) or {})
            for key in [k for k in values if k.startswith(f"{group}.")]:
                given[key[len(group) + 1:]] = values.pop(key)
            known = {f.name for f in fields(group_cls)}
            unknown += [f"{group}.{k}" for k in sorted(set(given) - known)]
            groups[group] = {k: v for k, v in given.items() if k in known}
        unknown = sorted(set(values) - {f.name for f in fields(cls)}) + unknown
        if unknown:
            raise ConfigError(f"unknown parameter(s): {', '.join(unknown)}")
        built = {group: replace(GROUPS[group](), **given) for group, given in groups.items()}
        for group, obj in built.items():
            VALIDATORS[group](obj)
        return cls(**values, **built)


def _check(ok: bool, message: str):
    if not ok:
        raise ConfigError(message)


def _is_int(v) -> bool:
    return isinstance(v, Integral) and not isinstance(v, bool)


def _is_real(v) -> bool:
    return isinstance(v, Real) and not isinstance(v, bool) and math.isfinite(v)


def _positive(cfg, name: str, allow_zero: bool = False):
    v = getattr(cfg, name)
    ok = _is_real(v) and (v >= 0 if allow_zero else v > 0)
    _check(ok, f"{name} must be a finite number {'>= 0' if allow_zero else '> 0'}, got {v!r}")


def _choice(cfg, name: str, options):
    v = getattr(cfg, name)
    _check(v in options, f"{name} must be one of {', '.join(options)}; got {v!r}")


def _int_at_least(cfg, name: str, low: int):
    v = getattr(cfg, name)
    _check(_is_int(v) and v >= low, f"{name} must be an integer >= {low}, got {v!r}")


def _fraction(cfg, name: str, low_open: bool, high_open: bool):
    v = getattr(cfg, name)
    ok = _is_real(v) and (v > 0 if low_open else v >= 0) and (v < 1 if high_open else v <= 1)
    span = f"{'(' if low_open else '['}0, 1{')' if high_open else ']'}"
    _check(ok, f"{name} must be in {span}, got {v!r}")


def _validate(cfg: LocalizerConfig):
    _choice(cfg, "algorithm", ALGORITHMS)
    _int_at_least(cfg, "num_particles", 2)
    _check(cfg.num_particles <= MAX_PARTICLES, f"num_particles must be <= {MAX_PARTICLES} (docs/failure_behaviour.md: "
           f"about 2.7 s per update at 100,000 on a 2-core machine), got {cfg.num_particles!r}")
    _check(_is_real(cfg.df_time_offset_s), f"df_time_offset_s must be a finite number, got {cfg.df_time_offset_s!r}")
    _check(cfg.seed is None or (_is_int(cfg.seed) and cfg.seed >= 0),
           f"seed must be a non-negative integer or unset, got {cfg.seed!r}")
    for name in ("bearing_sigma_deg", "sigma_q100_deg", "sigma_q40_deg", "obs_max_duration_s",
                 "gps_max_gap_s", "init_min_crossing_deg", "max_stamp_jump_s"):
        _positive(cfg, name)
    for name in ("process_noise_m", "obs_max_distance_m", "point_gate_sigma", "gps_sigma_m"):
        _positive(cfg, name, allow_zero=True)
    _check(cfg.init_min_crossing_deg < 90, f"init_min_crossing_deg must be < 90, got {cfg.init_min_crossing_deg!r}")
    _choice(cfg, "sigma_model", SIGMA_MODELS)
    _choice(cfg, "likelihood", LIKELIHOODS)
    _choice(cfg, "resampling", RESAMPLING)
    _choice(cfg, "bearing_encoding", BEARING_ENCODINGS)
    _choice(cfg, "init_method", INIT_METHODS)
    for name in ("calibrate_noise", "global_safety"):
        _check(isinstance(getattr(cfg, name), bool), f"{name} must be true or false, got {getattr(cfg, name)!r}")
    _int_at_least(cfg, "health_window", 3)
    _int_at_least(cfg, "moved_min_points", 3)
    _fraction(cfg, "health_p_value", low_open=True, high_open=True)
    for name in ("restart_log_odds", "moved_log_odds"):
        _positive(cfg, name)
    _fraction(cfg, "init_min_support", low_open=False, high_open=False)
    _fraction(cfg, "outlier_prob", low_open=False, high_open=True)
    _fraction(cfg, "ess_threshold", low_open=False, high_open=False)
    _fraction(cfg, "df_correlation", low_open=False, high_open=False)
    q = cfg.quality_min
    _check(_is_real(q) and 0 <= q <= 100, f"quality_min must be in [0, 100], got {q!r}")
    _choice(cfg, "point_weighting", POINT_WEIGHTINGS)
    _int_at_least(cfg, "obs_max_readings", 1)
    _int_at_least(cfg, "init_bearings", 2)
    _int_at_least(cfg, "init_max_points", cfg.init_bearings if _is_int(cfg.init_bearings) else 2)
    _int_at_least(cfg, "history_points", 1)
    prior = (cfg.prior_east, cfg.prior_north, cfg.prior_sigma_m)
    _check(all(p is None for p in prior) or all(_is_real(p) for p in prior),
           "prior_east, prior_north and prior_sigma_m are set together (all finite) or not at all")
    if cfg.has_prior:
        _positive(cfg, "prior_sigma_m")
    datum = (cfg.datum_lat, cfg.datum_lon)
    _check(all(d is None for d in datum) or all(_is_real(d) for d in datum),
           "datum_lat and datum_lon are set together (finite) or not at all")
    if cfg.has_datum:
        _check(-90 <= cfg.datum_lat <= 90, f"datum_lat must be in [-90, 90], got {cfg.datum_lat!r}")
        _check(-180 <= cfg.datum_lon <= 180, f"datum_lon must be in [-180, 180], got {cfg.datum_lon!r}")
    _check(cfg.datum_alt is None or _is_real(cfg.datum_alt), f"datum_alt must be a finite number, got {cfg.datum_alt!r}")
    for group, group_cls in GROUPS.items():
        _check(isinstance(getattr(cfg, group), group_cls), f"{group} must be a {group_cls.__name__}")
        VALIDATORS[group](getattr(cfg, group))


def _validate_afsa(a: AfsaConfig):
    _check(a.variant in AFSA_VARIANTS, f"afsa.variant must be one of {', '.join(AFSA_VARIANTS)}; got {a.variant!r}")
    for name in ("visual", "step", "crowd", "tolerance"):
        v = getattr(a, name)
        _check(_is_real(v) and v > 0, f"afsa.{name} must be a finite number > 0, got {v!r}")
    for name in ("try_number", "max_iterations"):
        v = getattr(a, name)
        _check(_is_int(v) and v >= 1, f"afsa.{name} must be an integer >= 1, got {v!r}")


def _validate_espf(e: EspfConfig):
    v = e.sbx_lambda
    _check(_is_real(v) and v >= 0, f"espf.sbx_lambda must be a finite number >= 0, got {v!r}")


def _validate_gfapf(g: GfapfConfig):
    for name in ("attraction", "rotation_max", "attract_min", "repel_max"):
        v = getattr(g, name)
        _check(_is_real(v) and v >= 0, f"gfapf.{name} must be a finite number >= 0, got {v!r}")
    _check(_is_int(g.iterations) and g.iterations >= 0, f"gfapf.iterations must be an integer >= 0, got {g.iterations!r}")
    _check(g.scale in ("spread", "absolute"), f"gfapf.scale must be spread or absolute; got {g.scale!r}")


def _validate_de(d: DeConfig):
    for name in ("f1", "f2"):
        v = getattr(d, name)
        _check(_is_real(v) and v > 0, f"de.{name} must be a finite number > 0, got {v!r}")
    _check(_is_real(d.cr) and 0 <= d.cr <= 1, f"de.cr must be in [0, 1], got {d.cr!r}")
    _check(_is_int(d.generations) and d.generations >= 0, f"de.generations must be an integer >= 0, got {d.generations!r}")


def _validate_agapf(g: AgapfConfig):
    for name in ("pc1", "pc2", "pm1", "pm2"):
        v = getattr(g, name)
        _check(_is_real(v) and 0 <= v <= 1, f"agapf.{name} must be in [0, 1], got {v!r}")
    _check(_is_real(g.a) and g.a > 0, f"agapf.a must be a finite number > 0, got {g.a!r}")


GROUPS = {"afsa": AfsaConfig, "espf": EspfConfig, "gfapf": GfapfConfig, "de": DeConfig, "agapf": AgapfConfig}
VALIDATORS = {"afsa": _validate_afsa, "espf": _validate_espf, "gfapf": _validate_gfapf, "de": _validate_de,
              "agapf": _validate_agapf}
