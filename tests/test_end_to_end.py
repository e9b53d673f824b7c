"""The public scenarios through the whole engine: accuracy against the CRLB with a generous bound, honesty, baseline."""
import numpy as np
import pytest

from aoa_localizer import LocalizerConfig
from aoa_localizer.simulation.evaluation import run
from aoa_localizer.simulation.scenarios import SCENARIOS, simulate


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_afsa_finds_the_emitter_in_every_public_scenario(name):
    for r in range(3):
        res = run(simulate(name, r), LocalizerConfig(seed=10000 + r))
        s = res.scores
        assert s["converged"], res.localizer.view().status
        assert s["error"] < 3 * s["crlb"] + 1.0, (r, s["error"], s["crlb"])


@pytest.mark.slow
def test_published_ellipse_is_honest_over_seeded_runs():
    """Mean NEES near 2 (not over-confident): the check the papers never made."""
    values = [run(simulate("seed", r), LocalizerConfig(seed=10000 + r)).scores["nees"] for r in range(15)]
    assert 0.8 < np.mean(values) < 4.0


BOOTSTRAP = {"algorithm": "sir", "sir.variant": "paper"}  # the bootstrap filter (sir's default is resample-move)


def _straight_rmse(**changes) -> float:
    errors = [
        run(simulate("straight", r), LocalizerConfig(seed=10000 + r).with_changes(**changes)).scores["error"]
        for r in range(3)
    ]
    return float(np.sqrt(np.mean(np.square(errors))))


@pytest.mark.slow
def test_afsa_beats_the_bootstrap_filter_where_it_collapses():
    """The filters alone (no safety layer, as the papers have them): AFSA's moves keep what SIR loses."""
    afsa = _straight_rmse(global_safety=False)
    sir = _straight_rmse(**BOOTSTRAP, global_safety=False)
    assert afsa < 0.5 * sir


@pytest.mark.slow
def test_the_safety_layer_rescues_the_bootstrap_filter_too():
    """The safety layer sits in the skeleton, so SIR gets its moves: it no longer collapses on `straight`."""
    assert _straight_rmse(**BOOTSTRAP) < 0.5 * _straight_rmse(**BOOTSTRAP, global_safety=False)


@pytest.mark.slow
def test_paper_variant_runs_and_localises_roughly():
    cfg = LocalizerConfig(seed=10000).with_changes(**{"afsa.variant": "paper"})
    s = run(simulate("seed", 0), cfg).scores
    assert s["converged"] and s["error"] < 20.0
