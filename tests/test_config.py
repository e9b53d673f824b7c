import math

import pytest

from aoa_localizer import AfsaConfig, ConfigError, LocalizerConfig
from aoa_localizer.core.spec import IncompleteGroup


def test_defaults_are_the_papers():
    c = LocalizerConfig()
    assert c.algorithm == "afsa" and c.num_particles == 100 and c.quality_min == 40
    assert math.radians(c.bearing_sigma_deg) ** 2 == pytest.approx(3.801e-4)
    assert c.process_noise_m == 1.0 and c.resampling == "systematic"
    a = c.afsa
    assert (a.visual, a.step, a.crowd, a.try_number) == (1.0, 0.3, 0.618, 50)


@pytest.mark.parametrize("change, words", [
    ({"num_particles": 0}, "num_particles"),
    ({"num_particles": 10.5}, "num_particles"),
    ({"num_particles": 100_001}, "num_particles"),
    ({"df_time_offset_s": float("nan")}, "df_time_offset_s"),
    ({"max_stamp_jump_s": 0.0}, "max_stamp_jump_s"),
    ({"calibrate_noise": "yes"}, "calibrate_noise"),
    ({"frequency_band_hz": [2e8, 1e8]}, "frequency_band_hz must be empty or \\[low, high\\]"),
    ({"frequency_band_hz": [1e8]}, "frequency_band_hz"),
    # YAML (a params file, -p NAME:=VALUE) reads 433e6 as text: the refusal says how to write it
    ({"frequency_band_hz": ["433e6", 4.4e8]}, "'433e6' was read as text; YAML reads 4.33e\\+08 or 433000000"),
    ({"bearing_sigma_deg": "nan"}, "bearing_sigma_deg must be a finite number in \\(0, 90\\], got 'nan'$"),
    ({"frequency_band_hz": [1e8, 2e8, 3e8]}, "frequency_band_hz"),
    ({"init_method": "guess"}, "init_method"),
    ({"health_window": 1}, "health_window"),
    ({"health_p_value": 1.0}, "health_p_value"),
    ({"algorithm": "kalman"}, "algorithm"),
    ({"quality_min": 120}, "quality_min"),
    ({"bearing_sigma_deg": -1.0}, "bearing_sigma_deg"),
    ({"bearing_sigma_deg": float("nan")}, "bearing_sigma_deg"),
    ({"outlier_prob": 1.0}, "outlier_prob"),
    ({"prior_east": 1.0}, "prior_east"),
    ({"datum_lat": 95.0, "datum_lon": 0.0}, "datum_lat"),
    ({"afsa.visual": 0.0}, "afsa.visual"),
    ({"afsa.variant": "greedy"}, "afsa.variant"),
    ({"seed": -3}, "seed"),
    ({"bogus": 1}, "bogus"),
])
def test_invalid_values_are_refused_by_name(change, words):
    with pytest.raises(ConfigError, match=words.replace(".", r"\.")):
        LocalizerConfig().with_changes(**change)


def test_flat_and_nested_dicts_build_the_same_config():
    flat = LocalizerConfig.from_dict({"algorithm": "sir", "afsa.step": 0.5})
    nested = LocalizerConfig.from_dict({"algorithm": "sir", "afsa": {"step": 0.5}})
    assert flat == nested and flat.afsa == AfsaConfig(step=0.5)
    assert LocalizerConfig.from_dict(flat.to_dict()) == flat


def test_seed_filter_groups_validate_and_round_trip():
    c = LocalizerConfig.from_dict({"algorithm": "gfapf", "gfapf.iterations": 4, "espf": {"sbx_lambda": 5.0}})
    assert c.gfapf.iterations == 4 and c.espf.sbx_lambda == 5.0
    assert LocalizerConfig.from_dict(c.to_dict()) == c
    with pytest.raises(ConfigError, match="espf.sbx_lambda"):
        LocalizerConfig().with_changes(**{"espf.sbx_lambda": -1.0})
    with pytest.raises(ConfigError, match="gfapf.scale"):
        LocalizerConfig().with_changes(**{"gfapf.scale": "metres"})


def test_the_readme_parameter_tables_are_the_declarations():
    """One declaration per parameter: the README's tables are written from it; regenerate them with
    `python -m aoa_localizer.param_docs README.md` after changing a parameter."""
    from pathlib import Path

    from aoa_localizer.tools.param_docs import BEGIN, END, block

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert readme[readme.index(BEGIN):readme.index(END) + len(END)] == block()


def test_the_rejection_reasons_table_is_the_reason_registry():
    """docs/design.md's table of rejection reasons is written from `Reason`: a reason is declared in one place."""
    from pathlib import Path

    from aoa_localizer.engine.rejections import Reason
    from aoa_localizer.tools.param_docs import REASONS_BEGIN, REASONS_END, reasons_block

    design = (Path(__file__).resolve().parents[1] / "docs" / "design.md").read_text()
    assert design[design.index(REASONS_BEGIN):design.index(REASONS_END) + len(REASONS_END)] == reasons_block()
    assert all(f"| `{r.value}` |" in design for r in Reason)


def test_every_parameter_is_declared_with_a_meaning_and_checked_by_its_declaration():
    from aoa_localizer.engine.config import parameter_specs

    specs = parameter_specs()
    assert len({p.name for p in specs}) == len(specs) == len(LocalizerConfig().to_dict())
    for p in specs:
        assert p.spec.doc and p.spec.kind in (int, float, bool, str, list)
        if p.spec.kind is str:
            assert p.default in p.spec.choices
    # init_min_crossing_deg < 90 used to be checked in Python only, num_particles' cap in ROS only
    with pytest.raises(ConfigError, match=r"init_min_crossing_deg must be a finite number in \(0, 90\)"):
        LocalizerConfig(init_min_crossing_deg=90.0)


def test_a_whole_group_given_to_with_changes_replaces_the_groups_settings():
    base = LocalizerConfig(seed=3)
    as_settings = base.with_changes(afsa=AfsaConfig(variant="paper", step=0.5))
    as_dict = base.with_changes(afsa={"variant": "paper"})
    assert (as_settings.afsa.variant, as_settings.afsa.step, as_dict.afsa.variant) == ("paper", 0.5, "paper")
    assert as_dict.afsa.step == base.afsa.step and as_settings.seed == 3


def test_a_group_set_only_in_part_is_refused_with_what_is_missing():
    with pytest.raises(IncompleteGroup, match="prior_east, prior_north and prior_sigma_m are set together") as err:
        LocalizerConfig(prior_east=1.0, prior_sigma_m=50.0)
    assert err.value.group == ("prior_east", "prior_north", "prior_sigma_m") and err.value.missing == ["prior_north"]
    with pytest.raises(IncompleteGroup, match=r"datum_lat and datum_lon are set together \(finite\)") as err:
        LocalizerConfig(datum_lon=10.0)
    assert err.value.missing == ["datum_lat"]


def test_param_docs_says_what_it_did(tmp_path, capsys):
    """Issue 53, part 4: `param_docs` printed nothing when it succeeded; it says whether it rewrote a document."""
    from aoa_localizer.tools.param_docs import BEGIN, END, main

    doc = tmp_path / "doc.md"
    doc.write_text(f"# Parameters\n{BEGIN}\nOUT OF DATE\n{END}\n")
    assert main([str(doc)]) == 0 and "generated tables rewritten from the code" in capsys.readouterr().out
    assert "OUT OF DATE" not in doc.read_text()
    assert main([str(doc)]) == 0 and "already match the code" in capsys.readouterr().out


def test_every_node_parameters_default_is_valid():
    """A node parameter's default passes its own declaration (an empty `cot_url`, "off", once refused every start
    in the graph tests while no fast test saw it)."""
    from aoa_localizer.ros.node_params import NODE_PARAMS

    refused = []
    for p in NODE_PARAMS:
        try:
            p.spec.check(p.name, p.default)
        except ConfigError as exc:
            refused.append(str(exc))
    assert refused == []
    assert any(p.name == "cot_url" and p.default == "" for p in NODE_PARAMS)  # the case that broke
