"""Entry point of `python -m aoa_localizer.param_docs`: the program is aoa_localizer.tools.param_docs, a Ctrl-C while it
loads is common/start_up.py's."""
import sys

from aoa_localizer.common.start_up import program

main = program("param_docs", "aoa_localizer.tools.param_docs", interrupted=130)

if __name__ == "__main__":
    sys.exit(main())
