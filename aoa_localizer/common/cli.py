"""Command-line pieces shared by the programs: engine options, `-p name=value` overrides, logging."""
from __future__ import annotations

import argparse
import json
import logging
import math
import shutil
import sys
from collections.abc import Callable

import yaml

from aoa_localizer.core.spec import ConfigError
from aoa_localizer.engine.config import ALGORITHMS, LocalizerConfig

HELP_WIDTH = 120  # the programs' docstrings, which --help prints as written, keep to the code's 120 columns


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """The programs' --help: the description as written, the usage and options wrapped as wide as it (or the
    terminal, when wider), and every option's default that is a value (an option left unset says in its help
    what unset means)."""

    def __init__(self, prog: str, **kwargs):
        kwargs.setdefault("width", max(shutil.get_terminal_size().columns - 2, HELP_WIDTH))
        super().__init__(prog, **kwargs)

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        unset = default is None or default is False or default == [] or default == argparse.SUPPRESS
        if unset or "%(default)" in text or not action.option_strings:
            return text
        return f"{text} (default: %(default)s)"


INTERRUPTED = 130  # the exit code after Ctrl-C: 128 + SIGINT, as a shell reports an interrupted program


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program handles a Ctrl-C, so both keep what is done."""


def raise_terminated(_signum, _frame):
    """A SIGTERM handler: the run stops as at a Ctrl-C."""
    raise Terminated


def interrupted(program: str, kept: str, exc: BaseException | None = None) -> int:
    """Ctrl-C (or SIGTERM, `exc` a Terminated): one line saying what is kept (no traceback), and INTERRUPTED."""
    print(f"{program}: interrupted ({'SIGTERM' if isinstance(exc, Terminated) else 'Ctrl-C'}); {kept}",
          file=sys.stderr)
    return INTERRUPTED


def seed_value(text: str) -> int:
    """argparse type of a seed: an integer >= 0 (numpy refuses negative seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a seed is an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"a seed is an integer >= 0, got {value}")
    return value


def finite_number(low: float, low_open: bool = False) -> Callable[[str], float]:
    """argparse type of a finite number at least `low` (above it when `low_open`)."""
    where = f"> {low:g}" if low_open else f">= {low:g}"

    def value(text: str) -> float:
        try:
            number = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"a finite number {where}, got {text!r}") from None
        if not (math.isfinite(number) and (number > low if low_open else number >= low)):
            raise argparse.ArgumentTypeError(f"a finite number {where}, got {text}")
        return number

    return value


def integer_in(low: int, high: int) -> Callable[[str], int]:
    """argparse type of an integer in [low, high]."""

    def value(text: str) -> int:
        try:
            number = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"an integer in [{low}, {high}], got {text!r}") from None
        if not low <= number <= high:
            raise argparse.ArgumentTypeError(f"an integer in [{low}, {high}], got {number}")
        return number

    return value


def add_topic_args(parser: argparse.ArgumentParser):
    parser.add_argument("--fix-topic", default="/gps/fix", help="the bag's GPS topic (sensor_msgs/msg/NavSatFix)")
    parser.add_argument("--bearing-topic", default="/df/bearing",
                        help="the bag's DF topic (a Vector3Stamped DF record, or a PoseWithCovarianceStamped bearing)")
    parser.add_argument("--heading-topic", default="/heading/imu",
                        help="the bag's IMU topic (sensor_msgs/msg/Imu), read with -p bearing_reference=vehicle "
                        "-p heading_source=imu")
    parser.add_argument("--station", action="append", type=station_value, metavar="NAME=FIX,BEARING[,HEADING]",
                        help="a DF station's topics in the bag (repeatable): its bearings are placed on its own GPS "
                        "track and fused with the other stations'; given, it replaces --fix-topic and --bearing-topic")


def station_value(text: str) -> tuple[str, dict[str, str]]:
    """argparse type of --station NAME=FIX_TOPIC,BEARING_TOPIC[,HEADING_TOPIC]."""
    name, _, rest = text.partition("=")
    topics = rest.split(",")
    if not (name.isidentifier() and name.isascii()) or len(topics) not in (2, 3) or not all(topics):
        raise argparse.ArgumentTypeError(f"a station is NAME=FIX_TOPIC,BEARING_TOPIC[,HEADING_TOPIC] with NAME a ROS "
                                         f"name token (letters, digits, _), got {text!r}")
    return name, dict(zip(("fix", "bearing", "heading"), topics, strict=False))


def bag_stations(args) -> dict[str, dict[str, str]] | None:
    """The --station options by name (None: one station on the fix and bearing topics); ConfigError when a name
    comes twice."""
    given = getattr(args, "station", None) or []
    names = [name for name, _ in given]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError(f"--station {', '.join(twice)} given more than once")
    return dict(given) or None


def bag_topics(args) -> dict[str, str]:
    """The bag topics the topic options name, by kind (msgs_adapters.bag.read_bag's keys)."""
    return {"fix": args.fix_topic, "bearing": args.bearing_topic, "heading": args.heading_topic}


def add_engine_args(parser: argparse.ArgumentParser, particles: int = LocalizerConfig().num_particles):
    """The engine's options; `particles` is the program's default number of particles (for the help)."""
    parser.add_argument("--algorithm", choices=ALGORITHMS, help="filter (unset: afsa, or the params file's)")
    parser.add_argument("--particles", type=int,
                        help=f"number of particles (unset: {particles}, or the params file's)")
    parser.add_argument("--seed", type=seed_value,
                        help="filter seed: the same seed reproduces a run (unset: a fixed seed, one input one answer)")
    parser.add_argument(
        "--params-file",
        metavar="YAML",
        help="parameters as a ROS 2 params file (aoa_localizer: ros__parameters: ...) or a flat mapping",
    )
    parser.add_argument(
        "-p",
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="any LocalizerConfig parameter, e.g. -p afsa.variant=paper -p quality_min=50 (ROS 2's NAME:=VALUE too)",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log the engine's decisions")


def _value(text: str):
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def load_params_file(path: str) -> dict:
    """Parameters from a YAML file: the ROS 2 form (`<node>: ros__parameters: {...}`, any node name) or flat."""
    try:
        with open(path) as fh:
            data = yaml.safe_load(fh) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"cannot read params file {path}: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"params file {path} must hold a mapping")
    for value in data.values():
        if isinstance(value, dict) and "ros__parameters" in value:
            return dict(value["ros__parameters"])
    return data


def param_changes(items: list[str]) -> dict:
    """`-p NAME=VALUE` items (or ROS 2's NAME:=VALUE) as config changes, each value read as JSON where it parses
    (numbers, booleans) and as text otherwise; raises ConfigError for an item without `=`."""
    changes = {}
    for item in items:
        name, sep, text = item.partition(":=") if ":=" in item else item.partition("=")
        if not sep:
            raise ConfigError(f"-p takes NAME=VALUE, got {item!r}")
        changes[name.strip()] = _value(text.strip())
    return changes


def config_from_args(args, base: LocalizerConfig | None = None) -> LocalizerConfig:
    """The config the options describe (file, then -p, then the short options); raises ConfigError. Every
    value given is checked, also one a later option overrides (a wrong -p is never silently dropped)."""
    changes = load_params_file(args.params_file) if args.params_file else {}
    changes.update(param_changes(args.param))
    cfg = (base or LocalizerConfig()).with_changes(**changes)
    short = {name: value for name, value in (("algorithm", args.algorithm), ("num_particles", args.particles),
                                             ("seed", args.seed)) if value is not None}
    return cfg.with_changes(**short) if short else cfg


OFFLINE_SEED = 1  # the filter's seed offline unless --seed: one input gives one answer, run after run


def seeded(cfg: LocalizerConfig) -> LocalizerConfig:
    """`cfg` with the offline programs' seed where it has none (a bag or a survey file is repeatable)."""
    return cfg if cfg.seed is not None else cfg.with_changes(seed=OFFLINE_SEED)


def setup_logging(verbose: bool):
    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s"
    )
