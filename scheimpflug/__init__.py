"""Scheimpflug light-sheet profiler: the instrument's own pipeline.

Pure numpy/scipy/OpenCV: hinge geometry and design (:mod:`.hinge`,
:mod:`.camera`, :mod:`.design`), the rig (:mod:`.rig`), stripe extraction,
the paper's calibration, rotary-axis location, reconstruction and scoring.
"""

__version__ = "0.1.0"
