"""Entry point of `python -m aoa_localizer.launch`: the program is aoa_localizer.ros.launch, a Ctrl-C while it
loads is common/start_up.py's."""
import sys

from aoa_localizer.common.start_up import program

main = program("launch", "aoa_localizer.ros.launch", interrupted=2)

if __name__ == "__main__":
    sys.exit(main())
