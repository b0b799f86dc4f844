"""tpnet animate (tpnet_ref.evaluation.animate): a GIF of the simulator beside TP-Net's rollout."""
from __future__ import annotations

import pytest

pytest.importorskip("h5py")
pytest.importorskip("matplotlib")
pytest.importorskip("pymunk")

from tpnet_ref.cli import main  # noqa: E402
from evaluation_helpers import weights_file  # noqa: E402,F401


def test_animate_writes_a_gif_with_every_input_frame(weights_file, tmp_path, capsys):
    from PIL import Image
    gif = tmp_path / "r.gif"
    assert main(["animate", "--weights", weights_file, "--last-frame", "9", "--every", "2",
                 "--dpi", "20", "-o", str(gif)]) == 0
    out = capsys.readouterr().out
    # inputs 0..3, then frames 4, 6, 8 and the last frame 9
    assert f"wrote {gif} (8 frames" in out and "E_p (squared)" in out
    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames == 8
        assert im.info["duration"] == 80 and im.info["loop"] == 0   # 12 fps in GIF hundredths
        first = im.convert("RGB").tobytes()
        im.seek(7)
        assert im.convert("RGB").tobytes() != first                  # the body moved


def test_animate_names_a_bad_last_frame(weights_file, tmp_path, capsys):
    assert main(["animate", "--weights", weights_file, "--last-frame", "2",
                 "-o", str(tmp_path / "r.gif")]) == 2
    assert "last_frame must lie in [4, 149]" in capsys.readouterr().err
    assert not (tmp_path / "r.gif").exists()
