"""The repository's documents stand on their own: links resolve, the contract names every topic and parameter."""
import re
from pathlib import Path

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
    sources = "".join((ROOT / "aoa_localizer" / "ros" / f).read_text() for f in ("node.py", "sim_vehicle.py"))
    topics = set(re.findall(r'create_(?:publisher|subscription)\(\s*[\w.]+,\s*"([^"]+)"', sources))
    topics |= set(re.findall(r'prefix \+ "([^"]+)"', sources))  # a station's inputs and path
    topics |= {"emitter/" + t for t in re.findall(r'make\(T\.\w+, "([^"]+)"', sources)}  # each channel's
    assert {"gps/fix", "df/bearing", "emitter/pose", "emitter/datum", "vehicle/path", "sim/truth"} <= topics
    for topic in topics:
        assert f"`{topic}`" in INTERFACE, topic


def test_the_contract_and_the_readme_cover_every_parameter():
    readme = (ROOT / "README.md").read_text()
    for p in parameter_specs() + NODE_PARAMS:
        assert f"`{p.name}`" in readme, p.name
    assert "README.md#parameters" in INTERFACE
