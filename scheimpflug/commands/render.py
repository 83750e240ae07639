"""`scheimpflug render` (placeholder until its issue lands)."""

from ..errors import ScheimpflugError


def add_parser(sub):
    p = sub.add_parser("render", help="(not available yet)")
    p.set_defaults(func=_run)
    return p


def _run(args):
    raise ScheimpflugError("'render' is not available yet in this version")
