"""The RViz and Foxglove layouts in config/ (docs/visualise.md): they parse, and every topic they show is one the
node publishes (the README's table), with the QoS it is published with where RViz asks for one."""
import json
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
LATCHED = {"/emitter/pose", "/emitter/fix", "/emitter/datum", "/emitter/channels"}


def published() -> set[str]:
    """The topics in the README's table of the node's topics ("| topic | type |")."""
    lines = (ROOT / "README.md").read_text().splitlines()
    start = lines.index("| topic | type | |") + 2
    rows = lines[start:lines.index("", start)]
    names = {"/" + name.lstrip("/") for row in rows for name in re.findall(r"`([a-z_/]+)`", row.split("|")[1])}
    assert {"/emitter/pose", "/emitter/posterior", "/vehicle/path", "/diagnostics"} <= names
    return names


def test_the_rviz_layout_shows_the_nodes_outputs_in_the_map_frame_with_their_qos():
    config = yaml.safe_load((ROOT / "config" / "aoa_localizer.rviz").read_text())
    manager = config["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == "map"
    topics = {d["Topic"]["Value"]: d["Topic"] for d in manager["Displays"] if "Topic" in d}
    assert {"/emitter/pose", "/emitter/particles", "/emitter/markers", "/emitter/posterior", "/vehicle/path",
            "/emitter/next_goal"} <= set(topics) <= published()
    for name, qos in topics.items():
        assert qos["Durability Policy"] == ("Transient Local" if name in LATCHED else "Volatile"), name
    pose = next(d for d in manager["Displays"] if d.get("Name") == "emitter/pose")
    assert abs(pose["Covariance"]["Position"]["Scale"] - 2.4477) < 1e-4  # sqrt(chi2_2(0.95)): the 95 % ellipse


def test_the_foxglove_layout_names_only_the_nodes_topics_and_each_of_its_panels():
    layout = json.loads((ROOT / "config" / "aoa_localizer.foxglove.json").read_text())
    panels = layout["configById"]
    scene = next(v for k, v in panels.items() if k.startswith("3D!"))
    geo = next(v for k, v in panels.items() if k.startswith("map!"))
    named = set(scene["topics"]) | set(geo["topicColors"])
    named |= {v["topicPath"] for k, v in panels.items() if k.startswith("RawMessages!")}
    named |= {v["topicToRender"] for k, v in panels.items() if k.startswith("DiagnosticSummary!")}
    assert scene["followTf"] == "map" and named <= published()
    assert {"/emitter/fix", "/gps/fix"} <= set(geo["topicColors"])  # the estimate on a street map, by the drive

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)  # every panel placed, none missing
