"""Named parts for ``--part``: the paper's plate, cylinder and pile, and test artefacts.

=============  ==========================================================================
name           what
=============  ==========================================================================
plate          calibration plate 120 (wide) × 89 (high) × 5 (thick) mm, measured face x = 0
cylinder       Ø100 × 108 mm, diamond knurl on the bottom 20 mm (pitch 1, depth 0.4, 30°)
knurled-ring   OD 69 / ID 45 × 15 mm ring, diamond knurl (pitch 1.2, depth 0.5, 30°)
box            cardboard box 252 × 165 × 62 mm lying flat, centred
tape           tape roll OD 120 / ID 76 × 48 mm lying flat
pile           ring on the table, box on the ring, tape on the box, all off-centre (paper)
blocker        2 × 60 × 80 mm plate centred on the axis, faces ⊥ x
sphere         Ø25.4 mm sphere on a Ø8 mm post, lowest point 30 mm above the table
ball-bar       two Ø20 mm spheres 100 mm apart on Ø6 mm posts, 30 mm above the table
=============  ==========================================================================

The pile (heights: ring 15 + box 62 + tape 48 = 125 mm): ring centred at
(−6, −4) mm; box centred at (25, 15) mm turned 20°; tape centred at (−35, 10) mm
in the box's own frame, i.e. off the box centre toward its −x end.  The box's
centre of mass is outside the ring's footprint, as in the paper's photo.
Values other than the paper's quoted dimensions are assumptions.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from scenes import generators as g
from scheimpflug.errors import MeshError

from .part import Assembly, Part, yaw_matrix

__all__ = ["PART_NAMES", "PILE_LAYOUT", "build_preset", "pile", "preset_parameters"]

#: preset name → (generator, default keyword arguments)
_SINGLE: dict[str, tuple[Callable[..., Part], dict]] = {
    "plate": (g.plate, {}),
    "cylinder": (g.knurled_cylinder, {}),
    "knurled-ring": (g.knurled_ring, {}),
    "box": (g.box, {}),
    "tape": (g.tape_roll, {}),
    "blocker": (g.blocker, {}),
    "sphere": (g.sphere, {}),
    "ball-bar": (g.ball_bar, {}),
}

#: The pile's placement: (x, y) [mm] and yaw [deg] of each body (tape: in the box frame).
PILE_LAYOUT = {"ring_xy_mm": (-6.0, -4.0), "ring_yaw_deg": 0.0,
               "box_xy_mm": (25.0, 15.0), "box_yaw_deg": 20.0,
               "tape_in_box_xy_mm": (-35.0, 10.0), "tape_yaw_deg": 0.0}

PART_NAMES = tuple(sorted([*_SINGLE, "pile"]))


def preset_parameters(name: str) -> tuple[str, ...]:
    """Keyword parameters a preset accepts as overrides.

    Parameters
    ----------
    name : str
        A preset name of :data:`PART_NAMES`.

    Returns
    -------
    tuple of str
        The preset generator's parameter names, sorted (for ``pile``:
        ``box``, ``layout``, ``ring``, ``tape``).

    Raises
    ------
    KeyError
        For a name that is not a preset.
    """
    if name == "pile":
        return tuple(sorted(inspect.signature(pile).parameters))
    fn = _SINGLE[name][0]
    return tuple(sorted(inspect.signature(fn).parameters))


def _call(name: str, fn: Callable, kwargs: dict):
    allowed = set(inspect.signature(fn).parameters)
    unknown = sorted(set(kwargs) - allowed)
    if unknown:
        raise MeshError(f"part {name!r}: unknown parameter {unknown[0]!r} "
                        f"(known: {', '.join(sorted(allowed))})")
    try:
        return fn(**kwargs)
    except TypeError as exc:
        raise MeshError(f"part {name!r}: bad parameter ({exc})") from None


def pile(ring: dict | None = None, box: dict | None = None, tape: dict | None = None,
         layout: dict | None = None) -> Assembly:
    """The paper's pile of sundries: knurled ring, cardboard box on it, tape roll on top.

    The ring stands on the table, the box lies on the ring's top and the tape
    on the box's top, each placed by :data:`PILE_LAYOUT` (the tape's position
    is given in the box's own frame).

    Parameters
    ----------
    ring : dict, optional
        Keyword overrides for :func:`~scenes.generators.knurled_ring`.
    box : dict, optional
        Keyword overrides for :func:`~scenes.generators.box`.
    tape : dict, optional
        Keyword overrides for :func:`~scenes.generators.tape_roll`.
    layout : dict, optional
        Overrides of :data:`PILE_LAYOUT` (positions [mm], yaws [deg]).

    Returns
    -------
    Assembly
        Named "pile", part frame, with object ids ring 1, box 2, tape 3.

    Raises
    ------
    MeshError
        For an unknown or bad generator parameter, or a dimension out of range.
    """
    lay = dict(PILE_LAYOUT, **(layout or {}))
    r = _call("pile.ring", g.knurled_ring, dict(ring or {}))
    b = _call("pile.box", g.box, dict(box or {}))
    t = _call("pile.tape", g.tape_roll, dict(tape or {}))
    r = r.posed((*lay["ring_xy_mm"], 0.0), lay["ring_yaw_deg"])
    z_box = float(r.mesh.bounds[1, 2])
    b = b.posed((*lay["box_xy_mm"], z_box), lay["box_yaw_deg"])
    tape_xy = (yaw_matrix(lay["box_yaw_deg"], (*lay["box_xy_mm"], 0.0))
               @ np.array([*lay["tape_in_box_xy_mm"], 0.0, 1.0]))[:2]
    t = t.posed((*tape_xy, float(b.mesh.bounds[1, 2])), lay["tape_yaw_deg"])
    parts = [replace(p, object_id=i + 1) for i, p in enumerate((r, b, t))]
    return Assembly(name="pile", parts=tuple(parts))


def build_preset(name: str, **overrides) -> Assembly:
    """A preset part with generator parameters overridden.

    Parameters
    ----------
    name : str
        A preset name of :data:`PART_NAMES`.
    **overrides
        Generator parameters (e.g. ``height_mm=50``; for ``pile``: ``ring``,
        ``box``, ``tape``, ``layout``).

    Returns
    -------
    Assembly
        One part named after the preset (the pile: three parts), part frame.

    Raises
    ------
    MeshError
        Unknown preset (lists the known ones), unknown or bad parameter, or a
        dimension out of range.
    """
    if name == "pile":
        return _call("pile", pile, overrides)
    if name not in _SINGLE:
        raise MeshError(f"unknown part {name!r} (known: {', '.join(PART_NAMES)}; "
                        "or a mesh file .stl/.ply/.obj, or a scene file .toml)")
    fn, defaults = _SINGLE[name]
    part = _call(name, fn, {**defaults, **overrides})
    return Assembly(name=name, parts=(part,))
