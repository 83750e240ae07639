"""The ``scheimpflug`` command line (INTERFACE.md).

Each subcommand lives in ``scheimpflug/commands/<name>.py`` and provides
``add_parser(subparsers)``, which registers its options and sets ``func``.
Heavy imports (Mitsuba) happen inside the command, so ``design`` and the
pipeline start fast.  Any :class:`~scheimpflug.errors.ScheimpflugError` is
printed on one line on stderr with exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from scheimpflug.errors import ScheimpflugError

__all__ = ["COMMANDS", "build_parser", "main"]

COMMANDS = ("design", "render", "calibrate", "axis", "reconstruct", "evaluate", "acceptance", "import",
            "demo")
_MODULES = {"import": "import_frames"}   # command name → module (``import`` is a keyword)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="scheimpflug",
        description="Scheimpflug laser light-sheet profiler: design, digital twin, calibration, "
                    "reconstruction and scoring.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"scheimpflug.app.commands.{_MODULES.get(name, name)}").add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        status = args.func(args)
    except ScheimpflugError as exc:
        msg = " ".join(str(exc).split())
        print(f"scheimpflug {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"scheimpflug {args.command}: interrupted", file=sys.stderr)
        return 130
    return int(status or 0)
