"""Entry point of `python -m aoa_localizer.sim_vehicle`: the program is aoa_localizer.ros.sim_vehicle, a Ctrl-C while it
loads is common/start_up.py's."""
import sys

from aoa_localizer.common.start_up import program, renamed

main = program("sim_vehicle", "aoa_localizer.ros.sim_vehicle", interrupted=0)
legacy_main = renamed(main, "sim_vehicle", "aoa_sim_vehicle")  # the console script's old name

if __name__ == "__main__":
    sys.exit(main())
