"""Mitsuba variant selection: the LLVM CPU JIT when a usable libLLVM exists, else scalar.

Mitsuba 3.9 / Dr.Jit 1.5 JIT-compile their ``llvm_*`` variants with a shared
libLLVM that must be version 17 or newer; with Debian's default LLVM 14–16 the
process can die inside LLVM ("Cannot select … fminimum") or the backend stays
inactive (docs/explanation/design-notes.md §6).  :func:`select_variant` therefore looks for the
library *before* Dr.Jit does, points Dr.Jit at a good one through
``DRJIT_LIBLLVM_PATH`` (only possible before ``drjit`` is imported), and falls
back to ``scalar_rgb`` with a warning when none is found.

Order of precedence
-------------------
1. ``SCHEIMPFLUG_VARIANT`` environment variable: used as given (a warning is
   issued if it names an ``llvm_*`` variant and no libLLVM ≥ 17 was found).
2. ``prefer`` (default ``llvm_ad_rgb``) when its backend is usable.
3. ``scalar_rgb`` with a :class:`RuntimeWarning`.

Emulating another machine
-------------------------
``SCHEIMPFLUG_LLVM_TARGET=avx2`` (or ``CPU:FEATURES:WIDTH``, e.g.
``haswell:+avx2,+fma,-avx512f:8``) makes Dr.Jit compile its kernels for that
CPU instead of this one (``jit_llvm_set_target`` of drjit-core), so that a
machine with AVX-512 can render what an AVX2-only machine renders and the
suite can be run as on one (``benchmarks/bench_cross_machine.py``).  numba
and OpenBLAS read their own variables (``NUMBA_CPU_NAME``,
``OPENBLAS_CORETYPE``) when they load.

The scalar fallback can load scenes and answer ray queries one ray at a time
only; :class:`sim.render.Renderer` needs a JIT variant and raises
:class:`~scheimpflug.errors.RenderError` otherwise (install ``libllvm19``:
``apt-get install libllvm19``).
"""

from __future__ import annotations

import ctypes
import glob
import os
import re
import subprocess
import sys
import warnings

from scheimpflug.errors import RenderError

__all__ = [
    "FALLBACK_VARIANT",
    "MIN_LLVM_VERSION",
    "find_libllvm",
    "LLVM_TARGETS",
    "is_jit_variant",
    "llvm_target_from_env",
    "llvm_version_from_path",
    "select_variant",
]

MIN_LLVM_VERSION = 17
FALLBACK_VARIANT = "scalar_rgb"
_ENV = "SCHEIMPFLUG_VARIANT"
_TARGET_ENV = "SCHEIMPFLUG_LLVM_TARGET"
#: named targets for SCHEIMPFLUG_LLVM_TARGET: (LLVM CPU, features, Dr.Jit vector width [lanes])
LLVM_TARGETS = {
    "avx2": ("haswell", "+sse2,+sse3,+ssse3,+sse4.1,+sse4.2,+popcnt,+avx,+avx2,+fma,+f16c,+bmi,+bmi2,"
                        "+lzcnt,+movbe,-avx512f,-avx512dq,-avx512bw,-avx512vl,-avx512cd", 8),
}
_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
          "/usr/lib/libLLVM*.so*", "/usr/lib64/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*",
          "/usr/lib/llvm-*/lib/libLLVM*.so*", "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
          "/usr/local/opt/llvm/lib/libLLVM*.dylib")


def llvm_version_from_path(path: str) -> int | None:
    """Major version of a libLLVM file from its (resolved) name or folder.

    ``libLLVM-19.so`` → 19, ``libLLVM.so.19.1`` → 19, ``/usr/lib/llvm-17/lib/libLLVM.so.1``
    → 17 (the folder wins over a bare soname number), ``libLLVM.17.dylib`` → 17.
    The path is tried as given, then with its symbolic links resolved.

    Parameters
    ----------
    path : str
        Path of a libLLVM shared library (need not exist).

    Returns
    -------
    int or None
        The LLVM major version [-]; None when neither name nor folder carries
        a version (a ``.so.1``/``.so.2`` suffix is a soname counter and is not
        taken for a version).
    """
    for candidate in (path, os.path.realpath(path)):
        base = os.path.basename(candidate)
        m = re.search(r"libLLVM-(\d+)", base) or re.search(r"llvm-(\d+)/", candidate) \
            or re.search(r"libLLVM\.(\d+)\.dylib", base)
        if m:
            return int(m.group(1))
        m = re.search(r"libLLVM\.so\.(\d+)", base)
        if m and int(m.group(1)) >= 3:  # .so.1 is a soname counter, not the LLVM major
            return int(m.group(1))
    return None


def _ldconfig_paths() -> list[str]:
    try:
        out = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True, timeout=10,
                             check=False).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    return [line.split("=>")[-1].strip() for line in out.splitlines() if "libLLVM" in line]


def find_libllvm() -> tuple[str | None, int | None]:
    """Find the newest libLLVM shared library on this machine.

    ``DRJIT_LIBLLVM_PATH`` wins when set (its version is read from the name,
    None if unreadable).  Otherwise ``ldconfig -p`` and the usual library
    folders are searched; among the existing files whose version can be read,
    the highest version wins (ties broken by the resolved path).

    Returns
    -------
    path : str or None
        Resolved path of the library (as given for ``DRJIT_LIBLLVM_PATH``);
        None when nothing is found.
    major_version : int or None
        Its LLVM major version [-]; None when nothing is found or (for
        ``DRJIT_LIBLLVM_PATH``) when the name carries no version.
    """
    forced = os.environ.get("DRJIT_LIBLLVM_PATH")
    if forced:
        return forced, llvm_version_from_path(forced)
    found: dict[str, int] = {}
    for path in _ldconfig_paths() + [p for g in _GLOBS for p in glob.glob(g)]:
        version = llvm_version_from_path(path)
        if version is not None and os.path.exists(path):
            found.setdefault(os.path.realpath(path), version)
    if not found:
        return None, None
    path = max(found, key=lambda p: (found[p], p))
    return path, found[path]


def is_jit_variant(variant: str) -> bool:
    """Whether a Mitsuba variant is one of the vectorised JIT variants.

    Parameters
    ----------
    variant : str
        Mitsuba variant name, e.g. ``llvm_ad_rgb`` or ``scalar_rgb``.

    Returns
    -------
    bool
        True for ``llvm_*`` and ``cuda_*`` variants.
    """
    return variant.startswith(("llvm_", "cuda_"))


def _llvm_usable() -> tuple[bool, str]:
    path, version = find_libllvm()
    if path is None:
        return False, "no libLLVM shared library was found"
    if version is None:
        return True, f"using {path} (version unknown)"
    if version < MIN_LLVM_VERSION:
        return False, f"the newest libLLVM found is version {version} ({path}); Dr.Jit needs ≥ 17"
    if "drjit" not in sys.modules and not os.environ.get("DRJIT_LIBLLVM_PATH"):
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    return True, f"using {path} (LLVM {version})"


def llvm_target_from_env() -> tuple[str, str, int] | None:
    """The Dr.Jit LLVM target asked for by ``SCHEIMPFLUG_LLVM_TARGET``, if any.

    Returns
    -------
    tuple of (str, str, int) or None
        LLVM CPU name, feature string and vector width [lanes]; None when the
        variable is unset or empty.

    Raises
    ------
    RenderError
        When the value is neither a named target (``avx2``) nor ``CPU:FEATURES:WIDTH``.
    """
    value = os.environ.get(_TARGET_ENV, "").strip()
    if not value:
        return None
    if value in LLVM_TARGETS:
        return LLVM_TARGETS[value]
    parts = value.split(":")
    if len(parts) != 3 or not parts[2].isdigit() or int(parts[2]) not in (4, 8, 16):
        raise RenderError(f"{_TARGET_ENV}={value!r}: expected one of {sorted(LLVM_TARGETS)} or "
                          "CPU:FEATURES:WIDTH with a width of 4, 8 or 16 lanes")
    return parts[0], parts[1], int(parts[2])


_TARGET_APPLIED: list[tuple[str, str, int]] = []


def _apply_llvm_target() -> None:
    target = llvm_target_from_env()
    if target is None or target in _TARGET_APPLIED:
        return
    import drjit as dr

    core = ctypes.CDLL(os.path.join(os.path.dirname(dr.__file__), "libdrjit-core.so"))
    set_target = core._Z19jit_llvm_set_targetPKcS0_j          # jit_llvm_set_target(cpu, features, width)
    set_target.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
    set_target.restype = None
    dr.llvm.Float(0.0)                                       # the LLVM backend is initialised
    set_target(target[0].encode(), target[1].encode(), target[2])
    _TARGET_APPLIED.append(target)


def _set(variant: str) -> str:
    import mitsuba as mi

    if mi.variant() != variant:
        mi.set_variant(variant)
    if variant.startswith("llvm_"):
        _apply_llvm_target()
    return variant


def select_variant(prefer: str = "llvm_ad_rgb") -> str:
    """Set and return the Mitsuba variant to render with.

    The order of precedence is in the module docstring: the
    ``SCHEIMPFLUG_VARIANT`` environment variable, then ``prefer`` when its
    backend is usable, then ``scalar_rgb``.  For an ``llvm_*`` variant this
    may set ``DRJIT_LIBLLVM_PATH`` (only when ``drjit`` is not yet imported).

    Parameters
    ----------
    prefer : str, default "llvm_ad_rgb"
        Variant wanted when its backend works.

    Returns
    -------
    str
        The variant now active in ``mitsuba``.

    Raises
    ------
    RenderError
        When the wanted variant (``SCHEIMPFLUG_VARIANT`` or ``prefer``) is not
        among the variants this Mitsuba build provides, or ``SCHEIMPFLUG_LLVM_TARGET``
        is malformed.

    Warns
    -----
    RuntimeWarning
        When falling back to ``scalar_rgb`` (no libLLVM ≥ 17, or the variant
        failed to load), naming the reason; or when ``SCHEIMPFLUG_VARIANT``
        forces an ``llvm_*`` variant although no usable libLLVM was found.
    """
    import mitsuba as mi

    wanted = os.environ.get(_ENV) or prefer
    llvm_target_from_env()                  # a bad SCHEIMPFLUG_LLVM_TARGET is refused before loading
    if wanted not in mi.variants():
        raise RenderError(f"Mitsuba variant {wanted!r} is not available "
                          f"(available: {', '.join(mi.variants())})")
    if not wanted.startswith("llvm_"):
        return _set(wanted)
    ok, why = _llvm_usable()
    if not ok and not os.environ.get(_ENV):
        warnings.warn(f"Mitsuba variant {wanted} unusable: {why}; falling back to "
                      f"{FALLBACK_VARIANT} (slow; install libllvm19 and/or set DRJIT_LIBLLVM_PATH)",
                      RuntimeWarning, stacklevel=2)
        return _set(FALLBACK_VARIANT)
    if not ok:
        warnings.warn(f"{_ENV}={wanted} forced although {why}", RuntimeWarning, stacklevel=2)
    try:
        return _set(wanted)
    except (ImportError, RuntimeError, AttributeError) as exc:
        warnings.warn(f"Mitsuba variant {wanted} failed to load ({exc}); falling back to "
                      f"{FALLBACK_VARIANT}", RuntimeWarning, stacklevel=2)
        return _set(FALLBACK_VARIANT)
