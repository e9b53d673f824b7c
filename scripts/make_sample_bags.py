"""Write the sample bags of bags/ from the ROS-free simulator (data seed 0), with their params files."""
from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import yaml

from aoa_localizer.scenarios import SCENARIOS, simulate
from msgs_adapters.bag import write_bag


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "bags"))
    parser.add_argument("scenarios", nargs="*", default=["seed", "urban"])
    args = parser.parse_args()
    for name in args.scenarios:
        data = simulate(name, 0)
        path = Path(args.out) / name
        shutil.rmtree(path, ignore_errors=True)
        write_bag(path, data.fixes, data.bearings, data.emitter_enu, data.scenario.datum)
        params = Path(args.out) / f"{name}.params.yaml"
        overrides = SCENARIOS[name].filter_overrides
        params.write_text(yaml.safe_dump({"aoa_localizer": {"ros__parameters": overrides}}) if overrides else "")
        if not overrides:
            params.unlink()
        print(f"{path}: {len(data.fixes)} fixes, {len(data.bearings)} DF records")


if __name__ == "__main__":
    main()
