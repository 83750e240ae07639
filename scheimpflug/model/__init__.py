"""The instrument as a model: the rig, its hinge-rule geometry, the camera and design.

Everything the digital twin (:mod:`sim`) needs to know about the instrument
lives here: :mod:`.rig` (frozen dataclasses, rig files, presets),
:mod:`.hinge` (closed forms of docs/explanation/design-notes.md §3, paper Eqs. 5, 11–12),
:mod:`.camera` (exact thin-lens projection onto a tilted, misaligned,
distorting sensor), :mod:`.design` (forward and inverse design) and
:mod:`.binning` (binned read-out with the same geometry).  Pure numpy; no I/O
beyond reading rig files.
"""

__all__ = ["binning", "camera", "design", "hinge", "rig"]
