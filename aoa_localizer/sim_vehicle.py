"""Entry point of `python -m aoa_localizer.sim_vehicle`: the program is aoa_localizer.ros.sim_vehicle, a Ctrl-C while it
loads is common/start_up.py's."""
import sys

from aoa_localizer.common.start_up import program

main = program("sim_vehicle", "aoa_localizer.ros.sim_vehicle", interrupted=0)

if __name__ == "__main__":
    sys.exit(main())
