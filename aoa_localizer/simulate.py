"""Entry point of `python -m aoa_localizer.simulate`; the program is aoa_localizer.tools.simulate."""
import sys

from aoa_localizer.tools.simulate import main

if __name__ == "__main__":
    sys.exit(main())
