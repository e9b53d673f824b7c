"""Entry point of `python -m aoa_localizer.replay`: the program is aoa_localizer.tools.replay, a Ctrl-C while it
loads is common/start_up.py's."""
import sys

from aoa_localizer.common.start_up import program, renamed

main = program("replay", "aoa_localizer.tools.replay", interrupted=130)
legacy_main = renamed(main, "replay", "aoa_replay")  # the console script's old name

if __name__ == "__main__":
    sys.exit(main())
