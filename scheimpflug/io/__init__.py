"""Files the instrument reads and writes: frame folders, PLY, atomic writes.

:mod:`.frames` (``manifest.json`` + ``frames/``, docs/reference/interface.md), :mod:`.ply`
(binary point clouds with provenance, meshes with per-face object ids) and
:mod:`.atomic` (write to a temporary name, then rename).
"""

__all__ = ["atomic", "frames", "ply"]
