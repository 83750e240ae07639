"""Options and helpers shared by several subcommands."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from scheimpflug.model.rig import PRESETS, Rig, load_preset, load_rig

__all__ = ["add_rig_options", "print_json", "rig_from_args"]


def add_rig_options(parser: argparse.ArgumentParser) -> None:
    """``--rig FILE.toml`` or ``--preset NAME`` (default: the paper rig)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--rig", metavar="RIG.toml", help="rig file (TOML, see INTERFACE.md)")
    group.add_argument("--preset", choices=PRESETS, help="built-in rig (default: paper)")


def rig_from_args(args: argparse.Namespace) -> Rig:
    if getattr(args, "rig", None):
        return load_rig(args.rig)
    return load_preset(getattr(args, "preset", None) or "paper")


def print_json(obj: Any) -> None:
    """Exactly one JSON object on stdout."""
    sys.stdout.write(json.dumps(obj, indent=2, allow_nan=False) + "\n")
    sys.stdout.flush()
