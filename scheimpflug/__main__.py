"""``python -m scheimpflug``: the command line."""

import sys

from scheimpflug.app.cli import main

sys.exit(main())
