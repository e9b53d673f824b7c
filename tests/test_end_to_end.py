"""The public scenarios through the whole engine: accuracy against the CRLB with a generous bound, honesty, baseline."""
import numpy as np
import pytest

from aoa_localizer import LocalizerConfig
from aoa_localizer.evaluation import run
from aoa_localizer.scenarios import SCENARIOS, simulate


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_afsa_finds_the_emitter_in_every_public_scenario(name):
    for r in range(3):
        res = run(simulate(name, r), LocalizerConfig(seed=10000 + r))
        s = res.scores
        assert s["converged"], res.localizer.status
        assert s["error"] < 3 * s["crlb"] + 1.0, (r, s["error"], s["crlb"])


def test_published_ellipse_is_honest_over_seeded_runs():
    """Mean NEES near 2 (not over-confident): the check the papers never made."""
    values = [run(simulate("seed", r), LocalizerConfig(seed=10000 + r)).scores["nees"] for r in range(15)]
    assert 0.8 < np.mean(values) < 4.0


def test_afsa_beats_the_bootstrap_filter_where_it_collapses():
    afsa, sir = [], []
    for r in range(3):
        data = simulate("straight", r)
        afsa.append(run(data, LocalizerConfig(seed=10000 + r)).scores["error"])
        sir.append(run(data, LocalizerConfig(algorithm="sir", seed=10000 + r)).scores["error"])
    assert np.sqrt(np.mean(np.square(afsa))) < 0.5 * np.sqrt(np.mean(np.square(sir)))


def test_paper_variant_runs_and_localises_roughly():
    cfg = LocalizerConfig(seed=10000).with_changes(**{"afsa.variant": "paper"})
    s = run(simulate("seed", 0), cfg).scores
    assert s["converged"] and s["error"] < 20.0
