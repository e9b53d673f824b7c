"""What `locate` makes of a survey as people write them (issue 67, items 6 and 7): no times (Lenth's table, tower
data), local times on every row, a column name with a typo, and a table a person reads."""
import json
import math
import re

import numpy as np
import pytest

from aoa_localizer.pooled.noise_family import quantile_of
from aoa_localizer.pooled.region import size_text
from aoa_localizer.tools import locate

LENTH = (locate.Path(__file__).resolve().parent.parent / "examples" / "lenth1981.csv").read_text().splitlines()


def untimed(path):
    """Lenth's eight readings twice (two ids), without their time column."""
    rows = [",".join(r.split(",")[1:]) for r in LENTH]
    rows += [r.replace(",lenth,", ",again,") for r in rows[1:]]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("model", ["pooled", "filter"])
def test_a_survey_without_times_gives_every_id_an_estimate(tmp_path, capsys, model):
    """A CSV without a `time` column was refused, and empty times skipped every row ("no usable row")."""
    out = tmp_path / "o.jsonl"
    assert locate.main([str(untimed(tmp_path / "s.csv")), "--model", model, "--output", str(out)]) == 0
    fixes = [json.loads(line) for line in out.read_text().splitlines()]
    assert sorted(f["id"] for f in fixes) == ["again", "lenth"]
    assert all(math.isfinite(f["lat"]) and f["state"] in ("tracking", "poorly_determined") for f in fixes)
    err = capsys.readouterr().err
    assert err.count("have no time") == 1 and "16 of 16 rows have no time" in err


@pytest.mark.slow
def test_a_report_of_a_survey_without_times_has_no_time_in_its_kml(tmp_path):
    assert locate.main([str(untimed(tmp_path / "s.csv")), "--report", str(tmp_path / "rep")]) == 0
    kml = (tmp_path / "rep" / "emitter.kml").read_text()
    assert "<TimeStamp>" not in kml and "lenth" in kml


def test_local_times_on_every_row_are_one_message_not_one_a_row(tmp_path, capsys):
    rows = ["time,lat,lon,azimuth_deg,station,id"] + [
        f"2024-05-01T10:{k:02d}:00,{r.split(',', 2)[1]},{r.split(',', 2)[2]}" for k, r in enumerate(LENTH[1:] * 3)]
    (tmp_path / "local.csv").write_text("\n".join(rows) + "\n")
    assert locate.main([str(tmp_path / "local.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    said = [line for line in err if "no UTC offset" in line]
    assert len(said) == 1 and "24 rows (lines 2, 3, 4, 5, 6, ...)" in said[0] and "--time-zone" in said[0]


def test_a_column_name_spelt_nearly_right_is_suggested(tmp_path, capsys):
    (tmp_path / "typo.csv").write_text("time,lat,lon,azimuth_dge\n1,46.5,-84.3,40\n")
    assert locate.main([str(tmp_path / "typo.csv")]) == 2
    assert "rename azimuth_dge -> azimuth_deg" in capsys.readouterr().err


def test_the_table_writes_sizes_as_a_person_reads_them(tmp_path, capsys):
    """`1.78e+03 x 1.77e+03` was the table's way to say 1780 m, and a wide region's warning said `2.99e+03 m`."""
    assert size_text(1780.4) == "1780" and size_text(123.4) == "123" and size_text(7.346) == "7.35"
    locate.main([str(untimed(tmp_path / "s.csv"))])
    table = capsys.readouterr().out
    assert not re.search(r"\de[+-]\d", table)
    three = tmp_path / "three.csv"  # three masts whose bearings barely agree: a region kilometres wide
    three.write_text("id,lat,lon,azimuth_deg,station\ntx,47.37,8.54,45.2,a\ntx,47.36,8.56,330.1,b\n"
                     "tx,47.365,8.53,80.3,c\n")
    locate.main([str(three)])
    out = capsys.readouterr().out
    assert "is wide for the range" in out and not re.search(r"\de[+-]\d", out)


def test_a_noise_posterior_on_one_grid_value_gives_that_values_bin_not_a_point():
    """`scale_deg_90: [3.16, 3.16]` said more than a grid with a step of x1.54 knows."""
    values = np.repeat(np.geomspace(1.0, 10.0, 5), 2)  # each value twice (the wild shares' hypotheses)
    weights = np.where(np.isclose(values, values[4]), 0.5, 0.0)
    low, high = quantile_of(values, weights, 0.05), quantile_of(values, weights, 0.95)
    step = math.sqrt(values[2] / values[0])  # half a grid step in log scale
    assert values[4] / step < low < values[4] < high < values[4] * step
    spread = np.full(values.size, 0.1)
    assert quantile_of(values, spread, 0.5) == pytest.approx(math.sqrt(10.0), rel=1e-9)  # even: the middle
