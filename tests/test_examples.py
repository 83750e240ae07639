"""The gallery's example scripts run (so they run in CI even without the docs build).

Each ``examples/plot_*.py`` is run as a script in this process (``runpy``, as
sphinx-gallery runs it, matplotlib on the Agg backend), at the size it has in the
docs: a 4 × 4 binned sensor and a handful of frames.  A script that raises, or
that draws no figure, fails.  One process for all of them shares Mitsuba's
start-up, which is most of a small example's time.
"""

from __future__ import annotations

import runpy
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("plot_*.py"))


def test_there_are_examples_for_each_gallery_topic():
    names = {p.stem for p in EXAMPLES}
    assert {"plot_design", "plot_render_frame", "plot_calibration", "plot_scan_error", "plot_dataset_errors",
            "plot_study_sensitivity"} <= names


@pytest.mark.render
@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_runs_and_draws(path, monkeypatch, capsys):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.close("all")
    monkeypatch.chdir(path.parent)
    runpy.run_path(str(path), run_name="__main__")
    try:
        figures = [plt.figure(n) for n in plt.get_fignums()]
        assert figures, f"{path.name} drew no figure"
        assert all(f.axes for f in figures)
    finally:
        plt.close("all")
    assert capsys.readouterr().out.strip(), f"{path.name} printed nothing"
