"""The digital twin: a Scheimpflug light-sheet profiler rendered with Mitsuba 3 / Dr.Jit.

Modules: :mod:`.variant` (Mitsuba variant and LLVM detection), :mod:`.scene`
(parts as a Mitsuba scene, ray queries), :mod:`.materials`, :mod:`.lightsheet`
(the Gaussian light sheet), :mod:`.render` (light-tracing renderer onto the
tilted thin-lens camera), :mod:`.sensor` (electrons → DN), :mod:`.stages`,
:mod:`.truth` (exact ground truth from geometry), :mod:`.scenarios` and
:mod:`.writer` (the frame folder).
"""

import os

# numba's OpenMP workers otherwise spin after each parallel kernel and steal the
# cores from Dr.Jit's render threads and the PNG encoder (measured: 157 → 138 ms
# per full frame, benchmarks/RESULTS.md).  Set before numba starts OpenMP.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
