"""Shared helpers: a Localizer fed from simple synthetic geometry; programs run in process."""
from types import SimpleNamespace

import numpy as np
import pytest

from aoa_localizer.engine.geodesy import LocalFrame

DATUM = (39.1, 117.2, 5.0)


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


def azimuth_from(frame, east, north, target):
    """Plane azimuth (deg from north) from (east, north) to target: exact enough near the datum."""
    return float(np.degrees(np.arctan2(target[0] - east, target[1] - north)) % 360)
