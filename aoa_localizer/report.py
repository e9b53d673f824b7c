"""Entry point of `python -m aoa_localizer.report`: the program is aoa_localizer.reporting.report, a Ctrl-C while it
loads is common/start_up.py's."""
import sys

from aoa_localizer.common.start_up import program

main = program("report", "aoa_localizer.reporting.report", interrupted=130)

if __name__ == "__main__":
    sys.exit(main())
