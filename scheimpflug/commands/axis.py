"""`scheimpflug axis` (placeholder until its issue lands)."""

from ..errors import ScheimpflugError


def add_parser(sub):
    p = sub.add_parser("axis", help="(not available yet)")
    p.set_defaults(func=_run)
    return p


def _run(args):
    raise ScheimpflugError("'axis' is not available yet in this version")
