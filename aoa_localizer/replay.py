"""Entry point of `python -m aoa_localizer.replay`; the program is aoa_localizer.tools.replay."""
import sys

from aoa_localizer.tools.replay import main

if __name__ == "__main__":
    sys.exit(main())
