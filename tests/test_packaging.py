"""The ROS package's metadata: package.xml, the launch file and the programs' --help (the colcon build itself
runs in .ci/colcon_check)."""
import ast
import re
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import rclpy

from aoa_localizer.ros import node, sim_vehicle
from aoa_localizer.simulation.scenarios import SCENARIOS

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_package_xml_is_an_ament_python_package_of_this_version_with_every_message_package_it_uses():
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.get("format") == "3" and root.findtext("name") == "aoa_localizer"
    assert root.findtext("export/build_type") == "ament_python"
    assert root.findtext("version") == PYPROJECT["project"]["version"]
    depends = {e.text for e in root.findall("exec_depend")}
    sources = "\n".join(p.read_text() for d in ("aoa_localizer", "msgs_adapters") for p in (ROOT / d).rglob("*.py"))
    used = set(re.findall(r"\b([a-z_]+_msgs|std_srvs|rcl_interfaces|builtin_interfaces)\b", sources))
    assert used and used <= depends, used - depends
    assert (ROOT / "resource" / "aoa_localizer").is_file()  # the ament index marker setup.py installs


def test_the_launch_file_parses_and_starts_the_installed_programs_with_its_arguments():
    tree = ast.parse((ROOT / "launch" / "localize_sim.launch.py").read_text())
    functions = {f.name for f in tree.body if isinstance(f, ast.FunctionDef)}
    assert "generate_launch_description" in functions
    calls = [c for c in ast.walk(tree) if isinstance(c, ast.Call)]
    keywords = [{k.arg: k.value for k in c.keywords} for c in calls]
    executables = {k["executable"].value for k in keywords if "executable" in k}
    assert executables == {"aoa_localizer", "aoa_sim_vehicle"} <= set(PYPROJECT["project"]["scripts"])
    arguments = {
        c.args[0].value: {k.arg: k.value.value for k in c.keywords if isinstance(k.value, ast.Constant)}
        for c in calls
        if getattr(c.func, "id", "") == "DeclareLaunchArgument"
    }
    assert set(arguments) == {"scenario", "speedup", "params_file"}
    assert arguments["scenario"]["default_value"] in SCENARIOS


def test_the_spectrum_launch_file_starts_one_node_per_band_on_the_shared_inputs():
    """launch/spectrum.launch.py: `edges` f0,...,fK give K nodes in namespaces band0... over adjacent half-open bands
    (each frequency in exactly one), reading /gps/fix and /df/bearing; the file is installed with the package."""
    from aoa_localizer.ros.bands import band_nodes

    source = (ROOT / "launch" / "spectrum.launch.py").read_text()
    tree = ast.parse(source)
    assert "generate_launch_description" in {f.name for f in tree.body if isinstance(f, ast.FunctionDef)}
    keywords = [{k.arg: k.value for k in c.keywords} for c in ast.walk(tree) if isinstance(c, ast.Call)]
    assert {k["executable"].value for k in keywords if "executable" in k} == {"aoa_localizer"}
    assert '("gps/fix", "/gps/fix"), ("df/bearing", "/df/bearing")' in source and "band_nodes(" in source
    assert "launch/spectrum.launch.py" in (ROOT / "setup.py").read_text()
    default = next(k["default_value"].value for k in keywords if "default_value" in k)
    assert band_nodes(default) == [("band0", [4.0e8, 4.5e8]), ("band1", [4.5e8, 5.0e8])]
    for bad, words in (("4e8", "at least two"), ("a,b", "separated by commas"), ("5e8,4e8", "increase"),
                       ("4e8,inf", "must be in")):
        with pytest.raises(ValueError, match=words):
            band_nodes(bad)


@pytest.mark.parametrize(
    "program, listed",
    [
        (node.main, ["num_particles", "diagnostics_period_s", "[read-only]"]),
        (sim_vehicle.main, ["scenario", "speedup", "gps_dropout_prob"]),
    ],
)
@pytest.mark.parametrize("flag", ["--help", "-h"])
def test_help_prints_usage_and_parameters_and_starts_nothing(cli, program, listed, flag):
    res = cli(program, "prog", flag)
    assert res.returncode == 0 and res.stdout.startswith("usage: ") and "ros2 run aoa_localizer aoa_" in res.stdout
    for word in listed:
        assert word in res.stdout
    assert not rclpy.ok()  # no ROS context was created: nothing joined a domain


def test_every_programs_help_shows_its_defaults_and_describes_its_options(cli, monkeypatch):
    """ROS-package issue: --rate, --timeout, --max-ellipse, --max-rate, --wait had no default in their help, and
    --scenario, --fix-topic, --bearing-topic no description; the usage wrapped narrower than the description."""
    from aoa_localizer.common.cli import HELP_WIDTH
    from aoa_localizer.reporting.report import main as report_main
    from aoa_localizer.ros.launch import main as launch_main
    from aoa_localizer.tools.param_docs import main as param_docs_main
    from aoa_localizer.tools.replay import main as replay_main
    from aoa_localizer.tools.simulate import main as simulate_main

    expected = {
        launch_main: ["--rate X", "(default: 10.0)", "(default: 600.0)", "(default: 50.0)", "public scenario",
                      "seed of the simulated data (default: 0)"],
        replay_main: ["(default: 400.0)", "(default: 3.0)", "the bag's GPS topic", "the bag's DF topic"],
        report_main: ["the bag's GPS topic (sensor_msgs/msg/NavSatFix) (default: /gps/fix)"],
        simulate_main: ["public scenario", "(default: seed)"],
        param_docs_main: ["DOCUMENT [DOCUMENT ...]", "a Markdown file holding a generated block"],
    }
    monkeypatch.setenv("COLUMNS", "80")  # a narrow terminal: the usage still wraps as wide as the description
    for main, words in expected.items():
        res = cli(main, "--help")
        text = " ".join(res.stdout.split())  # argparse wraps lines
        assert res.returncode == 0 and "(default: None)" not in text
        for word in words:
            assert word in text, (main.__module__, word)
        usage = res.stdout.split("\n\n")[0].splitlines()
        assert len(usage) == 1 or 100 < max(map(len, usage)) <= HELP_WIDTH, usage


def test_help_into_a_closed_pipe_is_not_an_error(monkeypatch):
    """`sim_vehicle --help | grep -q usage`: the reader leaves early and the next write fails; the program still
    exits 0 without a BrokenPipeError (CI's colcon check once failed on it)."""
    import io

    class ClosedPipe(io.StringIO):
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr("sys.stdout", ClosedPipe())
    assert sim_vehicle.main(["prog", "--help"]) == 0
    assert not rclpy.ok()


def test_the_nodes_help_names_every_output():
    """Issue 53, part 4: the node's --help summary left out emitter/posterior and emitter/next_goal."""
    from aoa_localizer.ros.node import usage

    text = usage()
    for topic in ("emitter/pose", "emitter/fix", "emitter/posterior", "emitter/next_goal", "emitter/datum",
                  "emitter/channels", "transmitter_<k>/pose", "/diagnostics", "cot_url"):
        assert topic in text, topic


def test_every_console_script_is_namespaced_and_an_old_name_says_its_new_one(capsys):
    """Issue 53, part 4: `replay` and `sim_vehicle` were generic names on a user's PATH. Each command is aoa_*; the
    round-3 names still run, saying the new name first."""
    from aoa_localizer import replay

    scripts = PYPROJECT["project"]["scripts"]
    new = {name for name, target in scripts.items() if not target.endswith(":legacy_main")}
    assert all(name.startswith("aoa_") for name in new) and len(new) == 8
    old = {name: target for name, target in scripts.items() if target.endswith(":legacy_main")}
    assert {f"aoa_{name}" for name in old} <= new
    with pytest.raises(SystemExit) as stop:
        replay.legacy_main(["--help"])
    out = capsys.readouterr()
    assert stop.value.code == 0 and "usage" in out.out
    assert out.err.startswith("replay: this command is now `aoa_replay`")
