"""Shared helpers: a Localizer fed from simple synthetic geometry; programs run in process; ROS processes in a
domain of the test's own."""
import itertools
import os
import random
import signal
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace


def _write_bytecode() -> None:
    """Where the environment turns bytecode off (PYTHONDONTWRITEBYTECODE), pytest rewrote every test module's asserts
    from source in each worker and each run, and each of the suite's processes compiled the package again: the
    suite writes it (`__pycache__`, which git ignores), as Python does by default."""
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    sys.dont_write_bytecode = False


_write_bytecode()

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from aoa_localizer.engine.geodesy import LocalFrame  # noqa: E402
from aoa_localizer.engine.scheduling.memory import one_blas_thread  # noqa: E402

# The suite's engine runs as the programs' do: BLAS on one thread (idle BLAS threads spin: scheduling/memory.py)
one_blas_thread()

DATUM = (39.1, 117.2, 5.0)
ROOT = Path(__file__).resolve().parent.parent


# Each xdist worker takes its own share of the domains (1-101, the range ROS recommends): the ROS tests of two
# workers can run at the same time, and a shared domain let one test's drive reach the other's node.
_WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:] or 0)
_WORKERS = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
_SHARE = 101 // _WORKERS
_domains = itertools.count(random.Random(os.getpid()).randrange(_SHARE))


def pytest_xdist_auto_num_workers(config):
    """`-n auto`: a worker per core, and at least four when the ROS tests run: their processes mostly wait on the
    clock of a drive played at 40x, so more workers than cores keep the cores busy (each worker's ROS tests in its
    own share of the domains); the fast tier keeps one per core (its workers' start-up would cost more than they
    save)."""
    cores = os.cpu_count() or 1
    return cores if "not ros" in (config.getoption("markexpr") or "") else max(cores, 4)



def pytest_collection_modifyitems(config, items):
    """The long tests first, the ROS ones (mostly waiting on a drive's clock) between those that compute, the quick
    ones last: xdist hands the tests out in this order, and the long ROS tests, last by file name, left the run's
    final minute to one or two workers beside a heavy job."""
    ros = [item for item in items if item.get_closest_marker("ros")]
    slow = [item for item in items if item.get_closest_marker("slow") and not item.get_closest_marker("ros")]
    quick = [item for item in items if not (item.get_closest_marker("slow") or item.get_closest_marker("ros"))]
    items[:] = [item for pair in itertools.zip_longest(ros, slow) for item in pair if item is not None] + quick


@pytest.fixture
def domain():
    """A ROS domain of this test's own, from this worker's share of 1-101."""
    return 1 + _WORKER * _SHARE + next(_domains) % _SHARE


def ros_env(domain):
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")


@pytest.fixture
def spawn(tmp_path):
    """Start `python -m ...` in a domain; every process is stopped at teardown, pass or fail."""
    started = []

    def start(module_args, domain):
        log = open(tmp_path / f"proc{len(started)}.log", "w")
        p = subprocess.Popen([sys.executable, "-m", *module_args], env=ros_env(domain), cwd=ROOT, stdout=log,
                             stderr=subprocess.STDOUT, start_new_session=True)
        p.log_path = log.name
        started.append((p, log))
        return p

    yield start
    for p, log in started:
        for sig in (signal.SIGINT, signal.SIGKILL):
            if p.poll() is None:
                try:
                    os.killpg(p.pid, sig)
                    p.wait(5)
                except (ProcessLookupError, subprocess.TimeoutExpired):
                    pass
        log.close()


@pytest.fixture
def cli(capsys):
    """Run a program's main(argv) in this process (no interpreter start-up): returncode, stdout, stderr."""
    def run(main, *args):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse refusing an option
            code = exc.code
        out, err = capsys.readouterr()
        return SimpleNamespace(returncode=code, stdout=out, stderr=err)
    return run


@pytest.fixture
def frame():
    return LocalFrame(*DATUM)


def track_of(loc, channel=None):
    """A channel's emitter track (None: the latest estimate's channel), for the tests that check the engine's
    internals."""
    return (channel or loc._channel()).track


def open_point(loc, station=""):
    """The readings of the default channel's open observation point at `station`."""
    return loc._channels.default.builder(station).readings


def azimuth_from(frame, east, north, target):
    """Plane azimuth (deg from north) from (east, north) to target: exact enough near the datum."""
    return float(np.degrees(np.arctan2(target[0] - east, target[1] - north)) % 360)
