"""Entry point of `python -m aoa_localizer.sim_vehicle`; the program is aoa_localizer.ros.sim_vehicle."""
import sys

from aoa_localizer.ros.sim_vehicle import main

if __name__ == "__main__":
    sys.exit(main())
