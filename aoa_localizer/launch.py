"""Entry point of `python -m aoa_localizer.launch`; the program is aoa_localizer.ros.launch."""
import sys

from aoa_localizer.ros.launch import main

if __name__ == "__main__":
    sys.exit(main())
