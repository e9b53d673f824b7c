"""Entry point of `python -m aoa_localizer.report`; the program is aoa_localizer.reporting.report."""
import sys

from aoa_localizer.reporting.report import main

if __name__ == "__main__":
    sys.exit(main())
