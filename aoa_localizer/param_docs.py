"""Entry point of `python -m aoa_localizer.param_docs`; the program is aoa_localizer.tools.param_docs."""
import sys

from aoa_localizer.tools.param_docs import main

if __name__ == "__main__":
    sys.exit(main())
