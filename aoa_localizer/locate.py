"""Entry point of `python -m aoa_localizer.locate`: the program is aoa_localizer.tools.locate, a Ctrl-C while it
loads is common/start_up.py's."""
import sys

from aoa_localizer.common.start_up import program

main = program("locate", "aoa_localizer.tools.locate", interrupted=130)

if __name__ == "__main__":
    sys.exit(main())
