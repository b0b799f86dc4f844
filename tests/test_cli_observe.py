"""``tpnet sim render`` -> ``tpnet observe`` -> ``tpnet predict`` on a short, small render, and the
commands' one-line errors."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tpnet_ref.cli import main

pytest.importorskip("cv2")


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    d = tmp_path_factory.mktemp("render")
    out = d / "run.mp4"
    assert main(["sim", "render", "--steps", "20", "--size", "200", "--distractors", "2",
                 "-o", str(out)]) == 0
    return out


def test_render_writes_the_video_and_its_calibration(video):
    calib = json.loads(video.with_suffix(".json").read_text())
    assert calib["fps"] == 45.0 and calib["frames"] == 20 and calib["image_size"] == [200, 200]
    assert calib["camera"]["left_wall_px"] == pytest.approx(200 / 45)
    assert calib["camera"]["floor_px"] == pytest.approx(200 * 44 / 45)
    assert (video.parent / calib["background"]).is_file()
    truth = np.load(video.parent / calib["truth"])
    from tpnet_ref.sim import simulate
    np.testing.assert_allclose(truth, simulate(1.3, 225.0, 30.0, 35.0, 20))   # 45 fps: the rows
    import cv2
    cap = cv2.VideoCapture(str(video))
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == 20


def test_observe_then_predict(video, tmp_path, capsys):
    win = tmp_path / "w.npy"
    assert main(["observe", str(video), "--camera", str(video.with_suffix(".json")),
                 "-o", str(win)]) == 0
    out = capsys.readouterr()
    assert "frames 0, 4, 8, 12 of 20" in out.out and out.err == ""
    w = np.load(win)
    truth = np.load(video.parent / "run.truth.npy")[0:16:4]
    assert w.shape == (4, 30, 2)
    # 200 px, mp4-compressed: a pixel is 0.225 world units; within half a pixel
    assert np.abs(w.mean(axis=1) - truth.mean(axis=1)).max() < 0.11
    r = np.sqrt(((w - w.mean(axis=1, keepdims=True)) ** 2).sum(axis=2)).mean(axis=1)
    assert np.abs(r - 2.0).max() < 0.1
    assert main(["predict", str(win), "--steps", "2", "-o", str(tmp_path / "p.npy")]) == 0
    assert capsys.readouterr().err == ""               # one body, in range: no warning
    assert np.load(tmp_path / "p.npy").shape == (2, 30, 2)


def test_png_frames_camera_numbers_and_median_background(tmp_path, capsys):
    d = tmp_path / "frames"
    assert main(["sim", "render", "--steps", "13", "--size", "160", "--fps", "90",
                 "--noise", "0", "-o", str(d)]) == 0
    pngs = sorted(d.glob("frame_*.png"))
    assert len(pngs) == 25 and (d / "calibration.json").is_file()
    cam = ",".join(str(v) for v in json.loads((d / "calibration.json").read_text())["camera"]
                   .values())
    win = tmp_path / "w.npy"
    # PNGs carry no frame rate: without the calibration file --fps is needed
    assert main(["observe", str(d), "--camera", cam, "-o", str(win)]) == 2
    assert "pass --fps" in capsys.readouterr().err
    assert main(["observe", str(d), "--camera", cam, "--fps", "90", "--frames", "2",
                 "--background", str(d / "background.png"), "-o", str(win)]) == 0
    assert "frames 0, 8 of 25" in capsys.readouterr().out
    truth = np.load(d / "truth.npy")[[0, 8]]
    assert np.abs(np.load(win).mean(axis=1) - truth.mean(axis=1)).max() < 0.06


@pytest.mark.parametrize("argv, msg", [
    (["sim", "render", "--steps", "5", "-o", "{tmp}/x.txt"], "must end in .mp4 or .avi"),
    (["sim", "render", "--steps", "5", "--size", "4", "-o", "{tmp}/x.mp4"], "size"),
    (["observe", "{tmp}/none.mp4", "--camera", "0,640,640", "-o", "{tmp}/w.npy"],
     "no such video"),
    (["observe", "{tmp}", "--camera", "5,5,640", "-o", "{tmp}/w.npy"], "degenerate"),
    (["observe", "{tmp}", "--camera", "0,640,640", "-o", "{tmp}/w.txt"], ".npy"),
])
def test_errors_are_one_line(tmp_path, capsys, argv, msg):
    argv = [a.format(tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and msg in err, err


def test_predict_warns_in_one_line_on_a_window_with_a_stray_point(video, tmp_path, capsys):
    w = np.load(video.parent / "run.truth.npy")[0:16:4]
    w = np.concatenate([w, np.tile([[[40.0, 5.0]]], (4, 1, 1))], axis=1)      # (4, 31, 2)
    np.save(tmp_path / "w.npy", w)
    assert main(["predict", str(tmp_path / "w.npy")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not look like one body" in err[0] and "drop_outliers" in err[0]
