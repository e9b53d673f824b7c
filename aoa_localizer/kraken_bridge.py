"""Entry point of `python -m aoa_localizer.kraken_bridge`; the program is aoa_localizer.ros.kraken_bridge."""
import sys

from aoa_localizer.ros.kraken_bridge import main

if __name__ == "__main__":
    sys.exit(main())
