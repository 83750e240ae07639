"""``python -m scheimpflug``: the command line."""

import sys

from scheimpflug.app.cli import main

if __name__ == "__main__":      # not when imported (the docs' API reference imports every module)
    sys.exit(main())
