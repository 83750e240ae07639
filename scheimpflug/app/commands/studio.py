"""``scheimpflug studio``: design a rig in the browser, on the engine of ``design`` (a local page)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from scheimpflug.app.commands._common import integer
from scheimpflug.errors import ScheimpflugError
from scheimpflug.model.rig import PRESETS, preset_tables, read_toml, rig_from_dict

__all__ = ["add_parser"]


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "studio",
        help="design a rig in the browser: a local page that redraws while a slider moves",
        description="Serve a local page (127.0.0.1 only, nothing from the internet) to design a rig: sliders "
                    "and fields for every rig key, the meridian plane to scale with the wedge of focus, the "
                    "field on the sheet, occlusion on a preset part at a table angle and its frame rendered by the "
                    "twin, a datasheet as vendors "
                    "write it, a pinned baseline, rigs proposed for "
                    "a wanted range (the inverse design of 'design --near-mm --far-mm') and exports (rig file, "
                    "datasheet, link, tolerance-study spec). Its API answers GET "
                    "/api/design?preset=NAME&TABLE.KEY=VALUE with exactly the JSON of 'design --json' for that "
                    "rig, GET /api/rig.toml?… with the rig file (docs/tutorials/design-in-the-studio.md). "
                    "Ctrl-C stops it.",
    )
    group = p.add_mutually_exclusive_group()
    group.add_argument("--rig", metavar="RIG.toml", help="start from this rig file (TOML; keys in "
                                                         "docs/reference/rig-keys.md)")
    group.add_argument("--preset", choices=PRESETS, help="start from this built-in rig (default: paper)")
    p.add_argument("--port", type=integer(0, 65535), default=0,
                   help="TCP port on 127.0.0.1 (default 0: a free port, printed)")
    p.add_argument("--no-browser", action="store_true", help="do not open the page in a web browser")
    p.set_defaults(func=run)
    return p


def _base(args: argparse.Namespace) -> tuple[dict | None, str, str | None]:
    if args.rig:
        tables = read_toml(args.rig, "rig file")
        rig_from_dict(tables)           # refused now, with the key named, not on the page
        return tables, f"rig file {args.rig!r}", str(Path(args.rig).resolve())
    name = args.preset or "paper"
    return preset_tables(name), f"preset '{name}'", None


def run(args: argparse.Namespace) -> int:
    from scheimpflug.app.studio.server import make_server

    tables, label, path = _base(args)
    try:
        server = make_server(args.port, tables, label, path)
    except OSError as exc:
        raise ScheimpflugError(f"--port {args.port}: cannot listen on 127.0.0.1:{args.port}: "
                               f"{exc.strerror or exc}") from None
    print(f"scheimpflug studio: {label} at {server.url} (Ctrl-C stops)", flush=True)
    if not args.no_browser:
        import webbrowser

        if not webbrowser.open(server.url):
            print("scheimpflug studio: no web browser found: open the address above", file=sys.stderr)
    try:
        server.serve_forever(poll_interval=0.2)
    except KeyboardInterrupt:
        print("scheimpflug studio: stopped", file=sys.stderr)
    finally:
        server.server_close()
    return 0
