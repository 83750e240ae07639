"""Without a usable LLVM (here forced with SCHEIMPFLUG_VARIANT=scalar_rgb), `render` stops with one
clear error and writes nothing; the design tool and the pipeline do not need Mitsuba at all."""

import os
import subprocess
import sys


def test_scalar_variant_render_is_one_clear_error(tmp_path):
    env = dict(os.environ, SCHEIMPFLUG_VARIANT="scalar_rgb")
    out = tmp_path / "frames"
    r = subprocess.run([sys.executable, "-m", "scheimpflug", "render", "calibration", "--out", str(out),
                        "--binning", "8", "--steps", "2", "--quiet"], capture_output=True, text=True, env=env)
    assert r.returncode == 2
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("scheimpflug render: error:") and "libllvm19" in last
    assert not out.exists()
