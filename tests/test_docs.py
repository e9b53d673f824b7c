"""The repository's documents stand on their own: links resolve, the contract names every topic and parameter."""
import math
import re
from pathlib import Path

import numpy as np
import pytest

from aoa_localizer.engine.config import parameter_specs
from aoa_localizer.ros.node_params import NODE_PARAMS

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", ROOT / "CHANGELOG.md", ROOT / "bags" / "README.md",
        *sorted((ROOT / "docs").glob("*.md"))]
INTERFACE = (ROOT / "docs" / "interface.md").read_text()


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(doc):
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", doc.read_text()):
        if "://" not in target:
            assert (doc.parent / target).exists(), f"{doc.name}: {target}"


def test_nothing_cites_documents_outside_the_repository():
    files = [p for d in ("aoa_localizer", "msgs_adapters", "tests", "scripts", "docs", "launch", "bags", ".ci")
             for p in (ROOT / d).rglob("*") if p.is_file()] + [p for p in ROOT.iterdir() if p.is_file()]
    checked = 0
    for path in files:
        if path.suffix in {".py", ".md", ".yaml", ".toml", ".xml", ".cfg", ""} and path.name != "test_docs.py":
            text = path.read_text(errors="replace")
            assert "INTERFACE.md" not in text and "BENCHMARKS.md" not in text, path
            checked += 1
    assert checked > 50


def test_the_contract_names_every_topic_the_programs_use():
    sources = "".join((ROOT / "aoa_localizer" / "ros" / f).read_text()
                      for f in ("node.py", "node_outputs.py", "sim_vehicle.py"))
    topics = set(re.findall(r'create_(?:publisher|subscription)\(\s*[\w.]+,\s*"([^"]+)"', sources))
    topics |= set(re.findall(r'\+ "([a-z_]+/[a-z_/]+)"', sources))  # a station's inputs and path
    topics |= {"emitter/" + t for t in re.findall(r'make\(T\.\w+, "([^"]+)"', sources)}  # each channel's
    assert {"gps/fix", "df/bearing", "emitter/pose", "emitter/datum", "vehicle/path", "sim/truth"} <= topics
    for topic in topics:
        assert f"`{topic}`" in INTERFACE, topic


def test_the_contract_and_the_readme_cover_every_parameter():
    readme = (ROOT / "README.md").read_text()
    for p in parameter_specs() + NODE_PARAMS:
        assert f"`{p.name}`" in readme, p.name
    assert "README.md#parameters" in INTERFACE


def test_the_failure_behaviour_page_states_the_limits_the_code_has():
    """docs/failure_behaviour.md stays true: each limit it states is the code's, and every rejection reason it names
    in backticks is one the engine counts."""
    import re

    from aoa_localizer.common import http_poll, kraken_csv
    from aoa_localizer.engine import channels
    from aoa_localizer.engine.rejections import REASONS
    from aoa_localizer.ros import kraken_bridge, node_monitor
    from msgs_adapters import bag_files, decompress

    page = (ROOT / "docs" / "failure_behaviour.md").read_text()
    mib = 1024 * 1024
    stated = {
        "above 1 THz": channels.FREQUENCY_MAX_HZ == 1e12,
        "past 4,096 entries": channels._HEARD_MAX == 4096,
        "remembers the latest 256": kraken_csv._VFOS_KEPT == 256,
        "its declared `uncompressed_size` and 128 MiB": decompress.CHUNK_MAX_BYTES == 128 * mib,
        "a message by 64 MiB": decompress.MESSAGE_MAX_BYTES == 64 * mib,
        "200 times its size (at least 64 MiB)": (decompress.FILE_RATIO, decompress.FILE_MIN_BYTES) == (200, 64 * mib),
        "less 1 GiB": decompress.DISK_MARGIN_BYTES == 1024 * mib,
        "(default 2 s, at most 60)": kraken_bridge.TIMEOUT_MAX_S == 60,
        "(default 4 MiB)": http_poll.DEFAULT_MAX_BYTES == 4 * mib,
        "within 0.1 s": http_poll.WATCH_S == 0.1,
        "a warning every 30 s": kraken_bridge.SKIPPED_SAY_EVERY_S == 30,
        "more than 80 % of the period": node_monitor._MAX_LOAD == 0.8,
        "over twice `diagnostics_period_s`": node_monitor._STALL_PERIODS == 2,
        "of 1.5 typical intervals": node_monitor._GAP_FACTOR == 1.5,
    }
    missing = [words for words in stated if words not in page]
    wrong = [words for words, true in stated.items() if not true]
    assert not missing and not wrong, (missing, wrong)
    assert bag_files.METADATA_MAX_BYTES == 4 * mib and "4 MiB" in page
    named = set(re.findall(r"`([a-z_]+)`", page))
    reasons_like = {n for n in named if n.startswith(("bearing_", "fix_", "bad_", "gps_", "channel_"))}
    reasons_like -= {"gps_max_gap_s", "gps_sigma_m", "channel_tolerance_hz", "channel_timeout_s", "bearing_reference",
                     "bearing_encoding", "bearing_sigma_deg", "fix_stamp_gaps", "fixes_missing_by_stamp",
                     "channel_limit"} | {"bearings_lost", "fixes_lost"}
    assert reasons_like <= set(REASONS), reasons_like - set(REASONS)


@pytest.mark.slow
def test_the_readmes_python_example_runs_as_written_and_finds_the_emitter(capsys):
    """The README's Python block is complete: run verbatim, it prints the estimate, which is within three times
    its 95 % ellipse of the emitter it names, and every input was used."""
    from pymap3d.vincenty import vdist

    from aoa_localizer.engine.crlb import ELLIPSE_95, inside_ellipse

    code = re.search(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    names: dict = {}
    exec(compile(code, "README.md", "exec"), names)
    est, emitter = names["est"], names["emitter"]
    distance, azimuth = vdist(est.lat, est.lon, *emitter)[:2]
    error = (distance * math.sin(math.radians(azimuth)), distance * math.cos(math.radians(azimuth)))
    assert inside_ellipse(error, est.cov, 9 * ELLIPSE_95) and distance < 20.0
    assert names["view"].status == "tracking" and not names["view"].rejected
    assert "emitter at 39.10" in capsys.readouterr().out


def test_the_localizers_public_members_are_the_documented_face():
    """Issue 52: docs/interface.md lists the Localizer's public face; a public member outside it (a program reaching
    inside, or a member added without its contract) fails here, and so does a listed name the class lacks."""
    from aoa_localizer import Localizer

    table = INTERFACE[INTERFACE.index("**The Localizer's public face.**"):INTERFACE.index("From Python the work is")]
    members = [line.split("|")[2] for line in table.splitlines() if line.startswith("| ") and "members" not in line]
    listed = {re.match(r"[a-z_]+", m).group() for row in members for m in re.findall(r"`([^`]+)`", row)}
    loc = Localizer()
    public = {n for n in dir(loc) if not n.startswith("_")}
    loc.close()
    assert public == listed - {"position"} and len(public) <= 15  # issue 65: about a dozen members


def test_the_old_face_answers_for_one_round_with_a_warning_naming_what_replaces_it():
    """Issue 65: each member the narrow face dropped still answers as before, with a DeprecationWarning naming its
    replacement, and every one of them is in docs/interface.md's list of the deprecated."""
    from aoa_localizer import Localizer, LocalizerConfig
    from aoa_localizer.engine.localizer import _DEPRECATED
    from aoa_localizer.simulation.scenarios import SCENARIOS, simulate

    data = simulate(SCENARIOS["seed"], 0)
    loc = Localizer(LocalizerConfig(seed=1))
    for event in data.inputs():
        loc.feed(event)
    loc.flush()
    deprecated = INTERFACE[INTERFACE.index("**Deprecated**"):INTERFACE.index("The sentences the programs print")]
    view, post = loc.view(), loc.posterior()

    def old(name):
        assert f"`{name}" in deprecated
        with pytest.warns(DeprecationWarning, match=f"Localizer.{name} is deprecated: .*"):
            return getattr(loc, name)

    for name in _DEPRECATED:
        old(name)
    assert old("estimate") is view.estimate and old("rejected") == view.rejected and old("status") == view.status
    assert old("frame") == view.frame == old("datum_frame")() and old("events") == view.events
    assert old("channel")().id == view.latest and old("track_status")() == view.track
    assert np.array_equal(old("recent_points")(), post.used_points)
    assert np.array_equal(post.recent_points(5), post.used_points[-5:]) and len(post.recent_points(0)) == 0
    assert np.array_equal(old("posterior_grid")().prob, post.grid().prob)
    assert old("vehicle_place")() == view.vehicles[""] and old("noise_summary")() == dict(view.noise)
    with pytest.warns(DeprecationWarning, match="setting Localizer.on_estimate is deprecated"):
        loc.on_estimate = print
    assert old("on_estimate") is print
    loc.close()
