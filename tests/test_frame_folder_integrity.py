"""Edited or interrupted frame folders (issue 34 item 7).

Before: a manifest saying ``"complete": false`` reconstructed without a word; after a
render killed with kill -9 the error named a missing frame, not the interrupted render
and how to resume it; two frames at one angle and two swapped angles passed; a frame
replaced by another image of the same size was used although ``checksums.jsonl`` said
otherwise.  Now: an unfinished folder is refused with the render's own command to resume
it (or opened with ``allow_incomplete``, warning); frames are verified against the ledger
when read; a rotary scan's repeated or out-of-order angles are warned about, naming the
frames.  One real render (binning 4) is killed with SIGKILL; the rest are tiny folders.
"""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from synth_frames import write_folder

from scheimpflug.errors import FrameError
from scheimpflug.io.folder import LOCK_NAME, FileLedger
from scheimpflug.io.frames import open_frame_folder

RIG = {"sensor": {"rows": 12, "columns": 20, "adc_bits": 12}}


def _folder(tmp_path, angles=(0.0, 10.0, 20.0, 30.0), *, scenario="rotary", render=True, ledger=True,
            complete=True) -> Path:
    """A folder as ``render`` writes it: manifest with ``render`` and ``complete``, ledger of every frame."""
    frames = [np.full((12, 20), 100 + 7 * i, np.uint16) for i in range(len(angles))]
    path = write_folder(tmp_path / "f", frames, [{"angle_deg": a} for a in angles], scenario=scenario, rig=RIG)
    m = json.loads((path / "manifest.json").read_text())
    m.update(complete=complete, **({"render": {"spp": 1}} if render else {}))
    (path / "manifest.json").write_text(json.dumps(m))
    if ledger:
        led = FileLedger(path)
        for i in range(len(angles)):
            led.record(i, [f"frames/{i:05d}.png"])
    return path


def _opened(path, **kw):
    """The folder opened, and the warnings it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ff = open_frame_folder(path, **kw)
    return ff, [str(w.message) for w in caught]


# ------------------------------------------------------------------ "complete": false


def test_an_unfinished_folder_is_refused_saying_how_to_resume(tmp_path):
    path = _folder(tmp_path, complete=False)
    with pytest.raises(FrameError, match=r'unfinished: its manifest.json says "complete": false \(4 of 4 frames '
                                         r"written\).*run the same `scheimpflug render` command again to resume"):
        open_frame_folder(path)


def test_an_unfinished_folder_opens_on_request_with_the_frames_present(tmp_path):
    path = _folder(tmp_path, complete=False)
    (path / "frames" / "00003.png").unlink()
    ff, notes = _opened(path, allow_incomplete=True)
    assert len(ff) == 3 and [r.angle_deg for r in ff.frames] == [0.0, 10.0, 20.0]
    assert any("3 of 4 frames written, first missing frames/00003.png" in n and "using the 3 frames present" in n
               for n in notes), notes
    assert ff.read(2)[0, 0] == 114


def test_an_unfinished_folder_names_the_stale_lock_owners_command(tmp_path):
    path = _folder(tmp_path, complete=False)
    (path / "frames" / "00002.png").unlink()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()                                                  # a pid that no longer runs
    owner = {"pid": dead.pid, "host": socket.gethostname(), "started": "2026-01-02T03:04:05+0000",
             "program": "scheimpflug render rotary --preset paper --binning 4 --out f"}
    (path / LOCK_NAME).write_text(json.dumps(owner))
    with pytest.raises(FrameError) as info:
        open_frame_folder(path)
    msg = str(info.value)
    assert "interrupted (pid" in msg and "no longer runs" in msg and owner["program"] in msg
    assert "3 of 4 frames written, first missing frames/00002.png" in msg and "does not exist" not in msg


def test_a_folder_being_rendered_names_the_process(tmp_path):
    path = _folder(tmp_path, complete=False)
    owner = {"pid": os.getpid(), "host": socket.gethostname(), "started": "now", "program": "scheimpflug render"}
    (path / LOCK_NAME).write_text(json.dumps(owner))
    with pytest.raises(FrameError, match=rf"being written now by pid {os.getpid()}.*wait for it to finish"):
        open_frame_folder(path)


def test_the_commands_option_opens_an_unfinished_folder(tmp_path, capsys):
    """`open_frames` is what a command with --allow-incomplete calls (scheimpflug.app.commands._common)."""
    from argparse import Namespace

    from scheimpflug.app.commands._common import open_frames

    path = _folder(tmp_path, complete=False)
    (path / "frames" / "00003.png").unlink()
    with pytest.raises(FrameError, match="resume it.*; or pass --allow-incomplete to use the 3 frames present$"):
        open_frames(path, Namespace(allow_incomplete=False))
    assert len(open_frames(path, Namespace(allow_incomplete=True))) == 3
    assert capsys.readouterr().err.startswith("warning: frame folder ")


@pytest.mark.parametrize("value", ["false", 0, None])
def test_complete_must_be_a_boolean(tmp_path, value):
    path = _folder(tmp_path)
    m = json.loads((path / "manifest.json").read_text())
    m["complete"] = value
    (path / "manifest.json").write_text(json.dumps(m))
    if value is None:                                            # absent or null: a folder of real frames
        assert len(open_frame_folder(path)) == 4
    else:
        with pytest.raises(FrameError, match="complete = .* must be true or false"):
            open_frame_folder(path)


# ------------------------------------------------------------------ checksums.jsonl


def test_a_replaced_frame_is_refused_when_read_naming_it(tmp_path):
    path = _folder(tmp_path)
    assert cv2.imwrite(str(path / "frames" / "00002.png"), np.full((12, 20), 999, np.uint16))   # same size, new image
    ff, notes = _opened(path)
    assert not notes and ff.read(1)[0, 0] == 107                  # the others are fine
    with pytest.raises(FrameError, match=r"00002.png' is not the file that was written there \(.*checksums.jsonl\)"):
        ff.read(2)
    with pytest.raises(FrameError, match="00002.png"):
        list(ff.map_frames(lambda rec, frame: frame.sum(), workers=2))


def test_a_frame_the_ledger_does_not_record_is_used_with_a_warning(tmp_path):
    path = _folder(tmp_path, ledger=False)
    FileLedger(path).record(0, ["frames/00000.png"])
    ff, notes = _opened(path)
    assert any("does not record 3 of the 4 frames (first frames/00001.png)" in n for n in notes), notes
    assert ff.read(3)[0, 0] == 121


def test_a_folder_without_a_ledger_is_read_as_before(tmp_path):
    ff, notes = _opened(_folder(tmp_path, ledger=False))
    assert not notes and not ff.checksums and ff.read(0)[0, 0] == 100


# ------------------------------------------------------------------ angles


def test_two_frames_at_one_angle_are_named(tmp_path):
    _, notes = _opened(_folder(tmp_path, angles=(0.0, 10.0, 10.0, 30.0)))
    assert any("frames[1] (frames/00001.png) and frames[2] (frames/00002.png) are at the same angle_deg = 10" in n
               for n in notes), notes


def test_swapped_angles_of_a_rendered_scan_are_named(tmp_path):
    _, notes = _opened(_folder(tmp_path, angles=(0.0, 20.0, 10.0, 30.0)))
    assert any("out of frame order: frames[2] (frames/00002.png) at 10° follows frames[1] (frames/00001.png) at 20°"
               in n and "swapped" in n for n in notes), notes


@pytest.mark.parametrize("angles, scenario, render", [
    ((0.0, 20.0, 10.0, 30.0), "rotary", False),    # a hand-made manifest may list frames in any order
    ((0.0, 0.0, 0.0, 0.0), "blocker", True),       # a blocker's frames are all at one angle by design
    ((0.0, -3.6, -7.2, -10.8), "rotary", True),    # FabScan's turn: decreasing is in order
])
def test_angles_that_are_legal_give_no_warning(tmp_path, angles, scenario, render):
    _, notes = _opened(_folder(tmp_path, angles=angles, scenario=scenario, render=render))
    assert not notes, notes


# ------------------------------------------------------------------ a real render killed with SIGKILL


@pytest.fixture(scope="module")
def killed_render(tmp_path_factory, variant):
    """`render rotary --binning 4 --step-deg 3` (120 frames) killed with SIGKILL after its third frame."""
    out = tmp_path_factory.mktemp("killed") / "scan"
    exe = Path(sys.executable).with_name("scheimpflug")
    proc = subprocess.Popen([str(exe), "render", "rotary", "--preset", "paper", "--binning", "4", "--step-deg", "3",
                             "--spp", "1", "--quiet", "--out", str(out)], start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    try:
        while not (out / "frames" / "00002.png").exists():
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"the render ended (status {proc.returncode}) or hung before its third frame")
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert json.loads((out / "manifest.json").read_text())["complete"] is False
    return out


@pytest.mark.render
def test_after_kill_9_the_error_names_the_interrupted_render_and_its_command(killed_render):
    with pytest.raises(FrameError) as info:
        open_frame_folder(killed_render)
    msg = str(info.value)
    assert "is unfinished" in msg and "interrupted" in msg and "no longer runs" in msg, msg
    assert "render rotary --preset paper --binning 4 --step-deg 3" in msg and "does not exist" not in msg, msg


@pytest.mark.render
def test_the_frames_of_a_killed_render_are_verified_when_read(killed_render, tmp_path):
    scan = tmp_path / "scan"
    shutil.copytree(killed_render, scan)
    ff, notes = _opened(scan, allow_incomplete=True)
    assert len(ff) >= 3 and any("using the" in n for n in notes), notes
    other = cv2.imread(str(scan / ff.frames[1].file), cv2.IMREAD_UNCHANGED)
    assert cv2.imwrite(str(scan / ff.frames[0].file), other)      # frame 0 replaced by frame 1's image
    with pytest.raises(FrameError, match=r"00000.png' is not the file that was written there"):
        ff.read(0)


@pytest.mark.render
def test_reconstruct_of_a_killed_render_says_how_to_resume_and_runs_on_request(killed_render, tmp_path, capsys):
    from scheimpflug.app.cli import main

    cal = tmp_path / "cal.json"
    truth = json.loads((killed_render / "truth" / "rig_truth.json").read_text())
    cal.write_text(json.dumps({"model": "paper", **{k: truth[k] for k in ("hinge_px", "F2_px_mm", "C_mm", "d0_mm")},
                               "columns": 304, "rows": 484}))
    base = ["reconstruct", str(killed_render), "--calibration", str(cal), "--axis-mm", "179.45", "--quiet",
            "--no-quality-filter"]
    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "a.ply")]) == 2
    err = capsys.readouterr().err
    assert "is unfinished" in err and "--allow-incomplete" in err and len(err.strip().splitlines()) == 1, err
    assert main([*base, "--allow-incomplete", "--out", str(tmp_path / "b.ply")]) == 0
    assert (tmp_path / "b.ply").exists() and "using the" in capsys.readouterr().err
