"""The progress convention of the library: one callback, no bars.

Long library functions (``calibrate_folder``, ``extract_folder``,
``sim.writer.render_scenario`` …) take an optional ``progress`` argument, a
callable ``progress(done, total)`` called after each step with the number of
steps done so far and the total.  The library never draws anything itself: the
application passes a :class:`scheimpflug.app.progress.Progress` bar (which is
such a callable), a test passes a list's ``append``-like recorder, a Dask
worker passes whatever reports back to its client.
"""

from __future__ import annotations

from typing import Protocol

__all__ = ["ProgressCallback", "report"]


# A Protocol is never instantiated: its (*args, **kwargs) constructor has nothing to document.
class ProgressCallback(Protocol):  # numpydoc ignore=PR01
    """``progress(done, total)``: ``done`` of ``total`` steps are finished.

    Any callable with this signature is a progress callback (a structural
    type: nothing needs to subclass it).  See :meth:`__call__`.
    """

    def __call__(self, done: int, total: int) -> None:
        """Report that ``done`` of ``total`` steps are finished.

        Parameters
        ----------
        done : int
            Steps finished so far [-], 0 ≤ done ≤ total.
        total : int
            Steps in all [-].
        """


def report(progress: ProgressCallback | None, done: int, total: int) -> None:
    """Call ``progress(done, total)`` if a callback was given.

    Parameters
    ----------
    progress : ProgressCallback or None
        The caller's callback; None reports nothing.
    done, total : int
        Steps finished and steps in all [-].
    """
    if progress is not None:
        progress(done, total)
