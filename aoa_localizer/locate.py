"""Entry point of `python -m aoa_localizer.locate`; the program is aoa_localizer.tools.locate."""
import sys

from aoa_localizer.tools.locate import main

if __name__ == "__main__":
    sys.exit(main())
