"""The layout says which code may use ROS: the engine, filters, models, reporting and the offline tools import
without rclpy; the public entry points stay where the README says."""
import subprocess
import sys

ROS_FREE = ["aoa_localizer", "aoa_localizer.engine.localizer", "aoa_localizer.engine.evaluation",
            "aoa_localizer.filters", "aoa_localizer.models", "aoa_localizer.reporting.report",
            "aoa_localizer.tools.replay", "aoa_localizer.tools.simulate", "aoa_localizer.tools.param_docs",
            "aoa_localizer.ros.node_params", "msgs_adapters.bag", "msgs_adapters.fields"]


def test_the_engine_and_the_offline_tools_import_with_rclpy_made_unimportable():
    code = ("import sys\n"
            "class NoRos:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name.split('.')[0] in ('rclpy', 'rcl_interfaces', 'std_srvs'):\n"
            "            raise ImportError(f'{name} is not allowed here')\n"
            "sys.meta_path.insert(0, NoRos())\n"
            + "".join(f"import {m}\n" for m in ROS_FREE)
            + "assert 'rclpy' not in sys.modules\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr


def test_the_documented_program_modules_are_thin_entry_points():
    import importlib

    for name, home in [("node", "ros.node"), ("sim_vehicle", "ros.sim_vehicle"), ("launch", "ros.launch"),
                       ("replay", "tools.replay"), ("report", "reporting.report"), ("simulate", "tools.simulate")]:
        source = importlib.util.find_spec(f"aoa_localizer.{name}").origin
        text = open(source).read()
        assert f"from aoa_localizer.{home} import main" in text and len(text.splitlines()) <= 8, name
