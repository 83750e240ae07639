"""Frame folder reading and validation: every bad input gives one clear FrameError."""

import json

import cv2
import numpy as np
import pytest
from synth_frames import write_folder

from scheimpflug.errors import FrameError
from scheimpflug.io.frames import open_frame_folder, read_frame

RIG = {"sensor": {"rows": 12, "columns": 20, "adc_bits": 12}}


def _folder(tmp_path, n=2, rig=RIG, shape=(12, 20), dtype=np.uint16):
    frames = [np.full(shape, 100 + i, dtype) for i in range(n)]
    recs = [{"stage_mm": 10.0 * i} for i in range(n)]
    return write_folder(tmp_path / "f", frames, recs, rig=rig)


def test_reads_lazily_and_validates(tmp_path):
    ff = open_frame_folder(_folder(tmp_path, 3))
    assert (len(ff), ff.rows, ff.columns, ff.scenario) == (3, 12, 20, "calibration")
    assert [r.stage_mm for r in ff.frames] == [0.0, 10.0, 20.0]
    frames = [f for _, f in ff]
    assert frames[2].dtype == np.uint16 and frames[2][0, 0] == 102
    assert ff.saturation_dn(frames[0]) == 4095.0


def test_no_rig_takes_size_from_first_frame(tmp_path):
    ff = open_frame_folder(_folder(tmp_path, rig=None, dtype=np.uint8))
    assert (ff.rows, ff.columns, ff.adc_bits) == (12, 20, None)
    assert ff.saturation_dn(ff.read(0)) == 255.0


def test_missing_folder_and_manifest(tmp_path):
    with pytest.raises(FrameError, match="does not exist"):
        open_frame_folder(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FrameError, match="no manifest.json"):
        open_frame_folder(tmp_path / "empty")


@pytest.mark.parametrize("text,match", [("{not json", "not valid JSON"), ("[1, 2]", "JSON object"),
                                        ('{"scenario": "x"}', "no 'frames'"),
                                        ('{"frames": []}', "non-empty"),
                                        ('{"frames": [{"stage_mm": 1}]}', "'file'"),
                                        ('{"frames": [{"file": "a.png", "stage_mm": "x"}]}',
                                         "finite number")])
def test_bad_manifest(tmp_path, text, match):
    (tmp_path / "manifest.json").write_text(text)
    with pytest.raises(FrameError, match=match):
        open_frame_folder(tmp_path)


def test_missing_frame(tmp_path):
    p = _folder(tmp_path)
    (p / "frames" / "00001.png").unlink()
    with pytest.raises(FrameError, match="00001.png.*does not exist"):
        open_frame_folder(p)


def test_corrupt_frame(tmp_path):
    p = _folder(tmp_path)
    (p / "frames" / "00001.png").write_bytes(b"\x89PNG garbage")
    ff = open_frame_folder(p)
    with pytest.raises(FrameError, match="unreadable or corrupt"):
        ff.read(1)


def test_wrong_size(tmp_path):
    p = _folder(tmp_path)
    cv2.imwrite(str(p / "frames" / "00001.png"), np.zeros((12, 21), np.uint16))
    ff = open_frame_folder(p)
    with pytest.raises(FrameError, match="expected 12 × 20"):
        ff.read(1)
    m = json.loads((p / "manifest.json").read_text())
    m["rig"]["sensor"]["rows"] = 13
    (p / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(FrameError, match="expected 13 × 20"):
        open_frame_folder(p)


def test_colour_frame(tmp_path):
    p = _folder(tmp_path)
    cv2.imwrite(str(p / "frames" / "00000.png"), np.zeros((12, 20, 3), np.uint8))
    with pytest.raises(FrameError, match="3 channels"):
        open_frame_folder(p)


def test_read_frame_missing(tmp_path):
    with pytest.raises(FrameError, match="does not exist"):
        read_frame(tmp_path / "x.png")
