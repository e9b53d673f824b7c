"""Entry point of `python -m aoa_localizer.node`: the program is aoa_localizer.ros.node, a Ctrl-C while it
loads is common/start_up.py's."""
import sys

from aoa_localizer.common.start_up import program

main = program("node", "aoa_localizer.ros.node", interrupted=0)

if __name__ == "__main__":
    sys.exit(main())
