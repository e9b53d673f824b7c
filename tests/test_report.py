"""The localisation report: files written, KML and GeoJSON as GIS tools read them, the ellipse's area."""
import json
import math
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from aoa_localizer.engine.crlb import ELLIPSE_95
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.types import Estimate, EstimateState, Transmitter
from aoa_localizer.reporting.export import KML_NS, geojson, kml
from aoa_localizer.reporting.report import main as report_main

ROOT = Path(__file__).resolve().parent.parent
FRAME = LocalFrame(39.1, 117.2, 5.0)


@pytest.fixture
def estimate():
    cov = np.array([[30.0, 12.0], [12.0, 10.0]])
    lat, lon, _ = FRAME.to_geodetic(1200.0, 800.0)
    return Estimate(stamp=1795000000.5, east=1200.0, north=800.0, lat=float(lat), lon=float(lon), cov=cov,
                    bearings_used=300, points_used=60, ess=80.0, algorithm="afsa")


TRACK = np.array([[0.0, 0.0], [1000.0, 400.0], [1500.0, 600.0]])


def inside(point, ring) -> bool:
    """Ray casting in (lon, lat)."""
    x, y = point
    hit = False
    for (x1, y1), (x2, y2) in zip(ring[:-1], ring[1:], strict=False):
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            hit = not hit
    return hit


def enu_area(ring):
    lon, lat = np.array(ring).T
    e, n = FRAME.to_enu(lat, lon)
    return 0.5 * abs(np.dot(e[:-1], n[1:]) - np.dot(e[1:], n[:-1]))


def test_kml_is_kml_with_a_closed_ellipse_around_the_estimate(estimate):
    root = ET.fromstring(kml(FRAME, [estimate], {"": TRACK}))
    ns = {"k": KML_NS}
    assert root.tag == f"{{{KML_NS}}}kml"
    names = [p.findtext("k:name", namespaces=ns) for p in root.iter(f"{{{KML_NS}}}Placemark")]
    assert names == ["emitter estimate", "95 % error ellipse", "vehicle track"]
    ring_text = root.find(".//k:Polygon/k:outerBoundaryIs/k:LinearRing/k:coordinates", ns).text
    ring = [tuple(map(float, c.split(",")[:2])) for c in ring_text.split()]
    assert ring[0] == ring[-1] and inside((estimate.lon, estimate.lat), ring)
    data = {d.get("name"): d.findtext("k:value", namespaces=ns) for d in root.iter(f"{{{KML_NS}}}Data")}
    assert data["algorithm"] == "afsa" and data["bearings_used"] == "300" and data["time"].startswith("2026")
    assert root.find(".//k:LineString/k:coordinates", ns).text.split()[0].startswith("117.2")


def test_geojson_structure_lon_lat_order_and_ellipse_area(estimate):
    gj = json.loads(json.dumps(geojson(FRAME, [estimate], {"": TRACK})))
    assert gj["type"] == "FeatureCollection"
    kinds = {f["geometry"]["type"]: f for f in gj["features"]}
    assert set(kinds) == {"Point", "Polygon", "LineString"}
    lon, lat = kinds["Point"]["geometry"]["coordinates"]
    assert (lon, lat) == pytest.approx((estimate.lon, estimate.lat)) and 117 < lon < 118 and 39 < lat < 40
    ring = kinds["Polygon"]["geometry"]["coordinates"][0]
    assert ring[0] == ring[-1] and len(ring) >= 4 and inside((lon, lat), ring)
    assert all(117 < p[0] < 118 and 39 < p[1] < 40 for p in ring)  # (lon, lat), not (lat, lon)
    assert len(kinds["LineString"]["geometry"]["coordinates"]) == 3
    assert kinds["Polygon"]["properties"]["bearings_used"] == 300
    a, b = np.sqrt(ELLIPSE_95 * np.linalg.eigvalsh(estimate.cov))
    assert enu_area(ring) == pytest.approx(math.pi * a * b, rel=0.01)


def report(*args):
    return subprocess.run([sys.executable, "-m", "aoa_localizer.report", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=240)


@pytest.mark.slow
def test_report_on_a_sample_bag_writes_every_file(tmp_path):
    res = report(ROOT / "bags/seed", "--out", tmp_path / "r", "--seed", 1)
    assert res.returncode == 0, res.stderr
    files = {p.name for p in (tmp_path / "r").iterdir()}
    assert files == {"map.png", "error.png", "emitter.kml", "emitter.geojson", "summary.md", "emitter_default.cot"}
    assert (tmp_path / "r/map.png").read_bytes()[:4] == b"\x89PNG"
    summary = (tmp_path / "r/summary.md").read_text()
    assert "Final error against the truth" in summary and "Inputs not used" in summary
    # every file it wrote is named, the TAK one too, and the file ends its last line (issue 67, item 8)
    assert all(f"`{name}`" in summary for name in files) and summary.endswith("`\n")


@pytest.mark.slow
def test_report_from_estimates_and_their_bag(tmp_path):
    out = tmp_path / "e.jsonl"
    rep = subprocess.run(
        [sys.executable, "-m", "aoa_localizer.replay", ROOT / "bags/seed", "--offline", "--output", out, "--seed", "2"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert rep.returncode == 0, rep.stderr
    res = report(out, "--bag", ROOT / "bags/seed", "--out", tmp_path / "r")
    assert res.returncode == 0, res.stderr
    last = json.loads(out.read_text().splitlines()[-1])
    gj = json.loads((tmp_path / "r/emitter.geojson").read_text())
    point = next(f for f in gj["features"] if f["geometry"]["type"] == "Point")
    assert point["geometry"]["coordinates"] == pytest.approx([last["lon"], last["lat"]])


@pytest.mark.slow
@pytest.mark.parametrize("case", ["garbage", "missing", "jsonl_without_bag", "bad_jsonl"])
def test_broken_input_exits_non_zero_with_a_message(tmp_path, case, cli):
    if case == "garbage":
        (tmp_path / "bag").mkdir()
        (tmp_path / "bag/x.mcap").write_bytes(b"not a bag" * 50)
        args = [tmp_path / "bag"]
    elif case == "missing":
        args = [tmp_path / "nothing"]
    elif case == "jsonl_without_bag":
        (tmp_path / "e.jsonl").write_text("{}\n")
        args = [tmp_path / "e.jsonl"]
    else:
        (tmp_path / "e.jsonl").write_text('{"stamp": 1}\n')
        args = [tmp_path / "e.jsonl", "--bag", ROOT / "bags/seed"]
    res = cli(report_main, *args, "--out", tmp_path / "r")
    assert res.returncode == 2 and "report:" in res.stderr


@pytest.mark.slow
def test_estimates_carry_their_configuration_and_the_report_redraws_with_it(tmp_path, cli):
    """ROS-package issue: `report urban.jsonl --bag bags/urban` without the params file drew 963 rays as wild
    instead of 356 and the wrong bound. The file's header line carries the configuration; the report uses it. The
    seed bag under urban's parameters (noise by quality): its bound is 2.5 m, 1.05 m under the defaults."""
    from aoa_localizer.tools.replay import main as replay_main

    params, bag = ROOT / "bags/urban.params.yaml", ROOT / "bags/seed"
    made = cli(replay_main, bag, "--offline", "--output", tmp_path / "u.jsonl", "--params-file", params, "--seed", 4)
    assert made.returncode == 0, made.stderr
    header = json.loads((tmp_path / "u.jsonl").read_text().splitlines()[0])["configuration"]
    assert header["sigma_model"] == "quality" and header["seed"] == 4
    from_file = cli(report_main, tmp_path / "u.jsonl", "--bag", bag, "--out", tmp_path / "a")
    direct = cli(report_main, bag, "--params-file", params, "--seed", 4, "--out", tmp_path / "b")
    assert from_file.returncode == direct.returncode == 0, from_file.stderr + direct.stderr
    a, b = ((tmp_path / d / "summary.md").read_text() for d in "ab")
    bound = [float(re.search(r"Cramer-Rao bound of the bearings used ([\d.]+) m", text)[1]) for text in (a, b)]
    assert bound[0] == bound[1] > 2.0, bound
    assert "seed 4" in a

    (tmp_path / "old.jsonl").write_text("\n".join((tmp_path / "u.jsonl").read_text().splitlines()[1:]))
    old = cli(report_main, tmp_path / "old.jsonl", "--bag", bag, "--out", tmp_path / "c")
    assert old.returncode == 0 and "has no configuration line" in old.stderr
    c = (tmp_path / "c/summary.md").read_text()
    assert "seed 1" in c  # the offline seed (cli.seeded): one bag, one report
    assert float(re.search(r"Cramer-Rao bound of the bearings used ([\d.]+) m", c)[1]) < 2.0  # the defaults'


@pytest.mark.slow
def test_rmse_curves_give_every_series_its_own_style_and_clip_a_diverged_one(tmp_path):
    """ROS-package issue: the --plot chart reused colours across 12 series and one diverged filter stretched the
    axis to 1e7."""
    from aoa_localizer.reporting.plots import CLIP_FACTOR, rmse_curves

    x = np.arange(60)
    curves = {f"f{i}": (x, 5.0 + i + 100.0 / (1 + x)) for i in range(11)}
    curves["diverged"] = (x, np.where(x > 30, 1e7, 8.0))
    drawn = rmse_curves(tmp_path / "c.png", "t", curves, bound=(x, 2.0 + 50.0 / (1 + x)))
    assert len(set(drawn["styles"].values())) == 12
    assert drawn["clip"] == pytest.approx(CLIP_FACTOR * 52.0)
    assert "diverged (diverged: clipped at 5.2e+04)" in drawn["styles"] and "f3" in drawn["styles"]
    assert (tmp_path / "c.png").stat().st_size > 10_000


@pytest.mark.slow
def test_a_report_of_two_stations_and_two_emitters_draws_and_exports_each(tmp_path):
    """Two cars hearing two carriers: one point and one ellipse per emitter (named by channel, with its frequency),
    one track per car, and the other emitter in the summary."""
    from aoa_localizer.report import main as report_main
    from aoa_localizer.simulation.fleet import PAIR, simulate_fleet
    from msgs_adapters.bag import write_bag

    emitters = {433.92e6: (1200.0, 800.0), 446.0e6: (300.0, 1200.0)}
    fleet = simulate_fleet(PAIR, emitters, 0)
    write_bag(tmp_path / "bag", [], [], datum=fleet.scenario.datum,
              stations={name: (fleet.fixes[name], fleet.bearings[name]) for name in PAIR})
    stations = [a for name in PAIR for a in ("--station", f"{name}=/{name}/gps/fix,/{name}/df/bearing")]
    assert report_main([str(tmp_path / "bag"), "--out", str(tmp_path / "r"), "--seed", "1", *stations]) == 0
    gj = json.loads((tmp_path / "r/emitter.geojson").read_text())
    by_name = {f["properties"]["name"]: f for f in gj["features"]}
    assert set(by_name) == {"emitter f433920000 (433.920 MHz)", "95 % error ellipse f433920000",
                            "emitter f446000000 (446.000 MHz)", "95 % error ellipse f446000000",
                            "vehicle track car1", "vehicle track car2"}
    for f, truth in emitters.items():
        point = by_name[f"emitter f{int(f)} ({f / 1e6:.3f} MHz)"]
        assert point["properties"]["frequency_hz"] == f
        lon, lat = point["geometry"]["coordinates"]
        e, n = LocalFrame(*fleet.scenario.datum).to_enu(lat, lon)
        assert math.hypot(e - truth[0], n - truth[1]) < 10.0
    root = ET.fromstring((tmp_path / "r/emitter.kml").read_text())
    assert len(list(root.iter(f"{{{KML_NS}}}Point"))) == 2
    summary = (tmp_path / "r/summary.md").read_text()
    assert "## Other emitters (channels)" in summary and "MHz" in summary


@pytest.mark.slow
def test_each_transmitter_of_a_bag_is_scored_against_its_own_truth(tmp_path, cli):
    """`simulate --emitters` writes each transmitter's truth on /sim/CHANNEL/truth; replay and report score each
    channel against its own (issue 53, item 2: the second was scored against the first's, 854 m). A bag whose one
    /sim/truth names no transmitter is scored against none of several channels, and says so."""
    from aoa_localizer.report import main as report_main
    from aoa_localizer.simulation.fleet import PAIR, simulate_fleet
    from aoa_localizer.tools import replay
    from msgs_adapters.bag import write_bag

    emitters = {433.92e6: (1200.0, 800.0), 446.0e6: (300.0, 1200.0)}
    fleet = simulate_fleet(PAIR, emitters, 0)
    stations = {name: (fleet.fixes[name], fleet.bearings[name]) for name in PAIR}
    write_bag(tmp_path / "own", [], [], {f"f{int(f)}": e for f, e in emitters.items()}, fleet.scenario.datum,
              stations=stations)
    write_bag(tmp_path / "one", [], [], emitters[433.92e6], fleet.scenario.datum, stations=stations)
    res = cli(replay.main, tmp_path / "own", "--offline", "--seed", "1", "--output", tmp_path / "own.jsonl")
    assert res.returncode == 0, res.stderr
    for f, (east, north) in emitters.items():
        line = next(x for x in res.stderr.splitlines() if x.startswith(f"channel f{int(f)}: error against"))
        assert f"(E {east:.1f} m, N {north:.1f} m" in line and float(line.split()[-2]) < 10.0
    assert report_main([str(tmp_path / "own"), "--out", str(tmp_path / "r"), "--seed", "1"]) == 0
    summary = (tmp_path / "r/summary.md").read_text()
    assert "inside its ellipse" in summary and "Final error against the truth" in summary
    assert "The receiver over its channels**: " in summary  # both channels calibrated: the pool is named
    res = cli(replay.main, tmp_path / "one", "--offline", "--seed", "1", "--output", tmp_path / "one.jsonl")
    assert "error against" not in res.stderr and "names no transmitter" in res.stderr, res.stderr


@pytest.mark.slow
def test_the_map_draws_the_posterior_grid_where_it_lies(tmp_path, monkeypatch):
    """map.png carries emitter/posterior's layer: an image on the map at the grid's place, and on the zoom at its
    place relative to the estimate."""
    from aoa_localizer.engine.config import LocalizerConfig
    from aoa_localizer.reporting import plots
    from aoa_localizer.simulation.evaluation import run
    from aoa_localizer.simulation.scenarios import simulate

    loc = run(simulate("seed", 1), LocalizerConfig(seed=1)).localizer
    est, grid = loc.view().estimate, loc.posterior().grid()
    figures = []
    monkeypatch.setattr(plots.plt, "close", figures.append)
    plots.map_figure(tmp_path / "map.png", loc.view().frame, {}, np.zeros((0, 5)), np.zeros(0, bool), est,
                     posterior=grid)
    side = grid.resolution * grid.value.shape[0]
    (main,), (zoom,) = figures[0].axes[0].images, figures[0].axes[1].images
    assert main.get_extent() == pytest.approx([grid.east0, grid.east0 + side, grid.north0, grid.north0 + side])
    assert zoom.get_extent()[0] == pytest.approx(grid.east0 - est.east)


def test_each_transmitter_of_a_shared_frequency_is_a_point_and_an_ellipse_in_kml_and_geojson(estimate):
    """Issue 54: a channel two transmitters share draws both, named "transmitter k of n", with share and state."""
    from dataclasses import replace

    def transmitter(east, north, share):
        lat, lon, _ = FRAME.to_geodetic(east, north)
        return Transmitter(east, north, float(lat), float(lon), np.eye(2) * 25.0, share, EstimateState.TRACKING)

    est = replace(estimate, transmitter_count=2, count_probability=0.99,
                  transmitters=[transmitter(1200.0, 800.0, 0.6), transmitter(600.0, 1300.0, 0.4)])
    features = geojson(FRAME, [est], {})["features"]
    named = {f["properties"]["name"]: f for f in features}
    second = named["emitter estimate: transmitter 2 of 2"]
    e, n = FRAME.to_enu(second["geometry"]["coordinates"][1], second["geometry"]["coordinates"][0])
    assert math.hypot(e - 600.0, n - 1300.0) < 0.01 and second["properties"]["share"] == 0.4
    assert "95 % error ellipse: transmitter 2 of 2" in named and len(features) == 6
    root = ET.fromstring(kml(FRAME, [est], {}))
    names = [p.findtext(f"{{{KML_NS}}}name") for p in root.iter(f"{{{KML_NS}}}Placemark")]
    assert names.count("emitter estimate: transmitter 1 of 2") == 1 and len(names) == 6
    line = json.loads(json.dumps(est.to_json_dict()))
    assert line["transmitter_count"] == 2 and line["count_probability"] == 0.99
    assert [t["share"] for t in line["transmitters"]] == [0.6, 0.4] and line["transmitters"][1]["state"] == "tracking"
