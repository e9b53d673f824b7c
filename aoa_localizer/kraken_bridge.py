"""Entry point of `python -m aoa_localizer.kraken_bridge`: the program is aoa_localizer.ros.kraken_bridge, a Ctrl-C
while it loads is common/start_up.py's."""
import sys

from aoa_localizer.common.start_up import program, renamed

main = program("kraken_bridge", "aoa_localizer.ros.kraken_bridge", interrupted=0)
legacy_main = renamed(main, "kraken_bridge", "aoa_kraken_bridge")  # the console script's old name

if __name__ == "__main__":
    sys.exit(main())
