"""The ``scheimpflug`` command line (docs/reference/interface.md).

Each subcommand lives in ``scheimpflug/app/commands/<name>.py`` and provides
``add_parser(subparsers)``, which registers its options and sets ``func``.
Heavy imports (Mitsuba) happen inside the command, so ``design`` and the
pipeline start fast.

Errors, always one line on stderr:

* a :class:`~scheimpflug.errors.ScheimpflugError` (bad input, named with the
  file, key or option and the reason) and a bad option (argparse) exit with
  status 2;
* an :class:`OSError` the command did not turn into a typed error (a file that
  cannot be written, a full disk) or a :class:`MemoryError` exits with status 2,
  naming the file;
* anything else is a bug of the toolkit: one line saying so and asking for a
  report, exit status 70 (``EX_SOFTWARE``).  ``--debug`` (or the environment
  variable ``SCHEIMPFLUG_DEBUG=1``) shows the Python traceback instead.

A warning the library raises (legal but suspicious input) and the command does not
print itself is one line too: ``scheimpflug CMD: warning: …``, without Python's file
and source line.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings

from scheimpflug.errors import ScheimpflugError

__all__ = ["COMMANDS", "EXIT_BUG", "EXIT_ERROR", "build_parser", "main"]

COMMANDS = ("design", "render", "calibrate", "axis", "reconstruct", "evaluate", "acceptance", "import",
            "dataset", "study", "identify", "demo", "studio", "rig", "compare", "twin")
_MODULES = {"import": "import_frames"}   # command name → module (``import`` is a keyword)
EXIT_ERROR = 2    # bad input, reported on one line
EXIT_BUG = 70     # an unexpected exception: a bug (sysexits.h EX_SOFTWARE)
_DEBUG_ENV = "SCHEIMPFLUG_DEBUG"


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (no usage block), exit status 2."""

    def error(self, message: str):  # noqa: D102 - argparse hook
        self.exit(EXIT_ERROR, f"{self.prog}: error: {' '.join(message.split())} "
                              f"(see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="scheimpflug",
        description="Scheimpflug laser light-sheet profiler: design, digital twin, calibration, "
                    "reconstruction and scoring.",
    )
    parser.add_argument("--debug", action="store_true",
                        help=f"show the Python traceback of an unexpected error (also {_DEBUG_ENV}=1)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"scheimpflug.app.commands.{_MODULES.get(name, name)}").add_parser(sub)
    return parser


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _os_error_line(exc: OSError) -> str:
    where = f" {exc.filename!r}" if exc.filename else ""
    return f"cannot access{where}: {exc.strerror or exc}"


def _warning_printer(name: str):
    """A ``warnings.showwarning`` that prints one line naming the command."""

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ARG001 - the hook's signature
        print(f"{name}: warning: {_one_line(message)}", file=sys.stderr)

    return show


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:          # --help, or a bad option (one line already printed)
        return exc.code if isinstance(exc.code, int) else EXIT_ERROR
    name = f"scheimpflug {args.command}"
    debug = args.debug or os.environ.get(_DEBUG_ENV, "") not in ("", "0")
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _warning_printer(name)
            status = args.func(args)
    except ScheimpflugError as exc:
        print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # last resort: one line, never a traceback unless asked for
        if debug:
            raise
        if isinstance(exc, OSError):
            print(f"{name}: error: {_one_line(_os_error_line(exc))}", file=sys.stderr)
            return EXIT_ERROR
        if isinstance(exc, MemoryError):
            print(f"{name}: error: out of memory: the job is too large for this machine "
                  "(fewer frames, a binned sensor or a smaller part)", file=sys.stderr)
            return EXIT_ERROR
        print(f"{name}: internal error: {type(exc).__name__}: {_one_line(exc)[:300]} — this is a "
              f"bug, please report it with the command line (rerun with --debug or {_DEBUG_ENV}=1 "
              "for the traceback)", file=sys.stderr)
        return EXIT_BUG
    return int(status or 0)
