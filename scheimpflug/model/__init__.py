"""The instrument as a model: the rig, its hinge-rule geometry, the camera and design.

Everything the digital twin (:mod:`sim`) needs to know about the instrument
lives here: :mod:`.rig` (frozen dataclasses, rig files, presets),
:mod:`.hinge` (closed forms of docs/explanation/design-notes.md §3, paper Eqs. 5, 11–12),
:mod:`.camera` (exact thin-lens projection onto a tilted, misaligned,
distorting sensor), :mod:`.design` (forward and inverse design; an ordinary camera's
report in :mod:`.camera_design`) and
:mod:`.binning` (binned read-out with the same geometry),
:mod:`.distortion` (OpenCV's lens distortion), :mod:`.instrument` (an instrument by
its calibrated parts, and its rig), :mod:`.housing` (a scanner's fixed boards) and
:mod:`.chain` (the camera chain's ``[chain]`` table: colour mosaic, tone curve, 8 bits, JPEG,
glare, blooming; named cameras).  Pure numpy; no I/O beyond reading rig and housing files.
"""

__all__ = ["binning", "camera", "camera_design", "chain", "design", "distortion", "hinge", "housing", "instrument",
           "rig"]
