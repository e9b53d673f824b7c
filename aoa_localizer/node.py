"""Entry point of `python -m aoa_localizer.node`; the program is aoa_localizer.ros.node."""
import sys

from aoa_localizer.ros.node import main

if __name__ == "__main__":
    sys.exit(main())
