"""tpnet_ref.observe: the camera path (calibration, contour, background subtraction, stray points,
frame timing) against synthetic masks and frames with known answers, and the NotOneBodyWarning."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import tpnet_ref
from tpnet_ref.checks import NotOneBodyWarning, OutsideTrainingRangeWarning, window_body_problem
from tpnet_ref.model import init_random
from tpnet_ref.observe import (BODY_INSET, MODEL_FRAME_S, Camera, drop_outliers,
                               frames_at_model_rate, model_rate_indices, outline_offset)
from tpnet_ref.sim.scene import ring_positions

cv2 = pytest.importorskip("cv2")
from tpnet_ref.observe import points_from_image, points_from_mask  # noqa: E402
from tpnet_ref.observe.render import (RenderSettings, background, body_mask,  # noqa: E402
                                  render_frame)

CAM = Camera(0, 430, 430)            # 10 px per world unit, the image edges are the walls/floor


def _disc(shape, cx, cy, r):
    """Pixels whose centre lies within ``r`` px of ``(cx, cy)`` (continuous coordinates)."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]] + 0.5
    return (xx - cx) ** 2 + (yy - cy) ** 2 <= r ** 2


def _ellipse(shape, cx, cy, a, b, angle):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]] + 0.5
    c, s = np.cos(angle), np.sin(angle)
    u = (xx - cx) * c + (yy - cy) * s
    v = -(xx - cx) * s + (yy - cy) * c
    return (u / a) ** 2 + (v / b) ** 2 <= 1.0


# --------------------------------------------------------------------------- Camera
def test_camera_maps_the_image_edges_to_the_walls_and_the_floor():
    cam = Camera(0, 640, 640)
    np.testing.assert_allclose(cam.to_world([[0, 640], [640, 0], [320, 320]]),
                               [[1, 1], [44, 44], [22.5, 22.5]])
    s = 640 / 43
    np.testing.assert_allclose(cam.to_world([0.5, 0.5]), [1 + 0.5 / s, 44 - 0.5 / s])
    p = np.random.default_rng(0).uniform(-50, 700, (20, 2))
    np.testing.assert_allclose(cam.to_pixels(cam.to_world(p)), p)
    box = Camera.for_box_image(450)
    np.testing.assert_allclose(box.to_world([[10, 440], [440, 10]]), [[1, 1], [44, 44]])


@pytest.mark.parametrize("args, msg", [
    ((10, 10, 100), "degenerate calibration"),
    ((100, 20, 100), "degenerate calibration"),
    ((0, float("nan"), 100), "right_wall_px must be finite"),
    (("0", 10, 100), "left_wall_px must be a number"),
])
def test_camera_refuses_a_degenerate_calibration_in_one_line(args, msg):
    with pytest.raises((ValueError, TypeError), match=msg) as e:
        Camera(*args)
    assert "\n" not in str(e.value)


def test_camera_parse_reads_numbers_or_a_calibration_file(tmp_path):
    assert Camera.parse("1.5,20,30") == Camera(1.5, 20, 30)
    f = tmp_path / "c.json"
    f.write_text('{"camera": {"left_wall_px": 1, "right_wall_px": 9, "floor_px": 7}, "fps": 45}')
    assert Camera.parse(str(f)) == Camera(1, 9, 7)
    with pytest.raises(FileNotFoundError, match="neither"):
        Camera.parse(str(tmp_path / "missing.json"))
    f.write_text('{"fps": 45}')
    with pytest.raises(ValueError, match="missing left_wall_px"):
        Camera.parse(str(f))


# --------------------------------------------------------------------------- points_from_mask
def test_disc_gives_n_points_on_its_edge_clockwise_from_the_top():
    cx, cy, r = 200.3, 180.6, 60.2
    p = points_from_mask(_disc((430, 430), cx, cy, r), CAM, 30, inset=0.0, smooth=False)
    c = CAM.to_world([cx, cy])
    assert p.shape == (30, 2)
    rad = np.sqrt(((p - c) ** 2).sum(axis=1))
    assert abs(rad.mean() - r / 10) < 0.02          # on the edge, within 0.2 px
    assert np.abs(p.mean(axis=0) - c).max() < 0.02          # 0.2 px
    step = np.sqrt((np.diff(np.vstack([p, p[:1]]), axis=0) ** 2).sum(axis=1))
    assert step.std() / step.mean() < 0.02           # uniform by arc length
    assert abs(p[0, 0] - c[0]) < 0.02 and p[0, 1] > c[1]     # starts at the top
    assert p[1, 0] > p[0, 0]                         # and runs clockwise (towards +x)


def test_inset_moves_the_contour_inwards_by_that_distance():
    m = _disc((430, 430), 215, 215, 80)
    c = CAM.to_world([215, 215])
    r0 = np.sqrt(((points_from_mask(m, CAM, inset=0.0) - c) ** 2).sum(axis=1)).mean()
    r1 = np.sqrt(((points_from_mask(m, CAM, inset=0.5) - c) ** 2).sum(axis=1)).mean()
    assert abs(r0 - r1 - 0.5) < 1e-3


def test_ring_mask_gives_its_outer_contour():
    m = _disc((430, 430), 215, 215, 70) & ~_disc((430, 430), 215, 215, 40)
    p = points_from_mask(m, CAM, 40, inset=0.0)
    r = np.sqrt(((p - CAM.to_world([215, 215])) ** 2).sum(axis=1))
    assert p.shape == (40, 2) and abs(r.mean() - 7.0) < 0.03 and r.min() > 6.8


def test_two_blobs_give_the_larger_one_only():
    m = _disc((430, 430), 120, 120, 50) | _disc((430, 430), 330, 300, 30)
    p = points_from_mask(m, CAM, inset=0.0)
    r = np.sqrt(((p - CAM.to_world([120, 120])) ** 2).sum(axis=1))
    assert abs(r.mean() - 5.0) < 0.03 and r.max() < 5.2


@pytest.mark.parametrize("mask, msg", [
    (np.zeros((50, 60), bool), "no foreground pixel"),
    (np.zeros((0, 5)), "is empty"),
    (np.zeros(5), "expected a 2-D array"),
    ("mask.png", "expected a 2-D array"),
    (np.pad(np.ones((1, 1)), 3), "too small"),
])
def test_bad_masks_are_one_clear_error(mask, msg):
    with pytest.raises((ValueError, TypeError), match=msg) as e:
        points_from_mask(mask, CAM)
    assert "\n" not in str(e.value)


def test_mask_touching_the_border_is_cut_by_it():
    # a disc centred on the left edge (the left wall's inner face): its cut is the wall
    m = _disc((430, 430), 0.0, 215.0, 60.0)
    p = points_from_mask(m, CAM, 60, inset=0.0)
    assert p[:, 0].min() == pytest.approx(1.0, abs=0.01)
    on_wall = np.abs(p[:, 0] - 1.0) < 0.01
    assert on_wall.sum() >= 15                         # the straight cut holds ~1/pi of the points
    assert p[:, 0].max() == pytest.approx(1.0 + 6.0, abs=0.05)


def test_rendered_body_contour_sits_on_the_particle_centres():
    """The offset correction: the filled body's outline, moved in by BODY_INSET, lies on the ring
    of particle centres (radius 2) at every resolution; without it 0.07 outside."""
    assert 0.05 < BODY_INSET < 0.1 and BODY_INSET == outline_offset()
    ring = ring_positions(20.3, 17.6)
    for size in (320, 640):
        cam = RenderSettings(size=size).camera
        m = body_mask(ring, size)
        p = points_from_mask(m, cam)
        r = np.sqrt(((p - [20.3, 17.6]) ** 2).sum(axis=1))
        assert abs(r.mean() - 2.0) < 0.01 and np.abs(p.mean(axis=0) - [20.3, 17.6]).max() < 0.02
        raw = points_from_mask(m, cam, inset=0.0)
        assert abs(np.sqrt(((raw - [20.3, 17.6]) ** 2).sum(axis=1)).mean() - 2.0 - BODY_INSET) \
            < 0.01


@settings(max_examples=12, deadline=None)
@given(dx=st.integers(-60, 60), dy=st.integers(-60, 60), a=st.floats(25, 60),
       b=st.floats(25, 60), angle=st.floats(0, 3.1))
def test_translating_the_mask_translates_the_points(dx, dy, a, b, angle):
    m = _ellipse((430, 430), 215.0, 215.0, a, b, angle)
    p = points_from_mask(m, CAM)
    moved = np.roll(np.roll(m, dy, axis=0), dx, axis=1)
    np.testing.assert_allclose(points_from_mask(moved, CAM), p + [dx / 10, -dy / 10], atol=1e-9)


@settings(max_examples=8, deadline=None)
@given(a=st.floats(25, 60), b=st.floats(25, 60), angle=st.floats(0, 3.1), k=st.integers(1, 3))
def test_rotating_the_mask_rotates_the_outline(a, b, angle, k):
    m = _ellipse((430, 430), 215.0, 215.0, a, b, angle)
    p = points_from_mask(m, CAM, 900)                # dense: the outline itself
    q = points_from_mask(np.rot90(m, k), CAM, 30)
    # rot90 turns the image counter-clockwise about its centre (22.5, 22.5) in world units
    t = -k * np.pi / 2
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    back = (q - 22.5) @ rot.T + 22.5
    # the rotated mask is the same pixel set turned: its points lie on the same outline
    a, b = p, np.roll(p, -1, axis=0)
    ab = b - a
    t = np.clip(((back[:, None] - a[None]) * ab[None]).sum(axis=2) / (ab * ab).sum(axis=1), 0, 1)
    d = np.sqrt(((back[:, None] - a[None] - t[..., None] * ab[None]) ** 2).sum(axis=2))
    assert d.min(axis=1).max() < 0.005                # on the polyline, to 0.05 px


# --------------------------------------------------------------------------- points_from_image
@pytest.mark.parametrize("grey", [False, True])
def test_points_from_image_finds_the_body_among_noise_and_distractors(grey):
    s = RenderSettings(size=640, noise=6.0, distractors=5, seed=3)
    ring = ring_positions(30.0, 12.0)
    bg = background(s)
    img = render_frame(ring, s, bg, np.random.default_rng(0))
    if grey:
        img, bg = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), cv2.cvtColor(bg, cv2.COLOR_BGR2GRAY)
    p = points_from_image(img, bg, s.camera)
    r = np.sqrt(((p - [30.0, 12.0]) ** 2).sum(axis=1))
    assert p.shape == (30, 2)
    assert np.abs(p.mean(axis=0) - [30.0, 12.0]).max() < 0.03 and abs(r.mean() - 2.0) < 0.03


def test_points_from_image_errors():
    bg = np.zeros((40, 40, 3), np.uint8)
    with pytest.raises(ValueError, match="shapes differ"):
        points_from_image(bg, bg[:, :30], CAM)
    with pytest.raises(ValueError, match="identical to the background"):
        points_from_image(bg, bg, CAM)
    with pytest.raises(ValueError, match="grey .* or colour"):
        points_from_image(np.zeros((4, 4, 2)), np.zeros((4, 4, 2)), CAM)


# --------------------------------------------------------------------------- drop_outliers
def _frames_of_one_case():
    from tpnet_ref.sim import simulate
    return simulate(1.6, 200.0, 39.8, 39.6, 400)[::4]         # hits two walls


def test_drop_outliers_keeps_the_points_of_simulated_bodies():
    frames = _frames_of_one_case()
    for f in frames:                                   # without the eager spur test: every one
        assert len(drop_outliers(f, spur_factor=None)) == 30
    kept = sum(len(drop_outliers(f)) for f in frames)  # with it: a body point, rarely
    assert kept >= 0.995 * 30 * len(frames)


def test_drop_outliers_removes_stray_points_and_invents_none():
    ring = ring_positions(30.0, 30.0)
    pts = np.vstack([ring[:10], [[5.0, 40.0]], ring[10:], [[30.0, 30.2]], [[38.0, 30.0]]])
    kept, mask = drop_outliers(pts, return_mask=True)
    np.testing.assert_array_equal(kept, ring[[*range(30)]][np.r_[0:10, 10:30]])
    assert mask.sum() == 30 and not mask[[10, 31, 32]].any()
    # a second, smaller blob goes too; too few points are returned as they are
    two = np.vstack([ring, ring_positions(10.0, 10.0, 12, 1.0)])
    np.testing.assert_array_equal(drop_outliers(two), ring)
    np.testing.assert_array_equal(drop_outliers(pts[:4]), pts[:4])
    # an outline broken in two places (occluded) is still one body
    broken = np.delete(ring, np.r_[5:10, 20:25], axis=0)
    np.testing.assert_array_equal(drop_outliers(broken), broken)
    assert window_body_problem([broken] * 4) is None


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2 ** 31), k=st.integers(0, 4))
def test_drop_outliers_does_not_depend_on_the_point_order(seed, k):
    rng = np.random.default_rng(seed)
    pts = np.vstack([ring_positions(*rng.uniform(8, 37, 2)) + rng.normal(0, 0.05, (30, 2)),
                     rng.uniform(1, 44, (k, 2))])
    perm = rng.permutation(len(pts))
    _, mask = drop_outliers(pts, return_mask=True)
    _, mask_p = drop_outliers(pts[perm], return_mask=True)
    np.testing.assert_array_equal(mask_p, mask[perm])


# --------------------------------------------------------------------------- frame timing
@pytest.mark.parametrize("fps, first", [(45.0, [0, 4, 8, 12]), (90.0, [0, 8, 16, 24]),
                                        (30.0, [0, 3, 5, 8]), (480.0, [0, 43, 85, 128])])
def test_model_rate_indices_pick_the_nearest_frames(fps, first):
    t = np.arange(400) / fps
    idx = model_rate_indices(t, count=4)
    assert idx.tolist() == first
    assert np.abs(t[idx] - MODEL_FRAME_S * np.arange(4)).max() <= 0.5 / fps + 1e-12
    frames = [f"f{i}" for i in range(400)]
    assert frames_at_model_rate(t, frames, count=4) == [f"f{i}" for i in first]
    arr = np.arange(400) * 2
    np.testing.assert_array_equal(frames_at_model_rate(t, arr, count=4), arr[first])


def test_model_rate_indices_refuse_a_video_too_slow_or_too_short():
    with pytest.raises(ValueError, match="frame rate too low"):
        model_rate_indices(np.arange(100) / 10.0, count=4)
    with pytest.raises(ValueError, match="too short"):
        model_rate_indices(np.arange(10) / 45.0, count=4)
    with pytest.raises(ValueError, match="strictly increasing"):
        model_rate_indices([0.0, 0.1, 0.1])
    assert len(model_rate_indices(np.arange(45) / 45.0)) == 12     # 0 .. 44/45 s


# --------------------------------------------------------------------------- NotOneBodyWarning
@pytest.fixture(scope="module")
def net():
    return init_random(seed=3, dtype="float64")


def _warnings_of(window, net):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", OutsideTrainingRangeWarning)
        tpnet_ref.predict(window, model=net)
        tpnet_ref.rollout(window, 2, model=net)
    return [w for w in caught if issubclass(w.category, OutsideTrainingRangeWarning)]


def test_clean_windows_do_not_warn(net):
    f = _frames_of_one_case()
    for i in range(0, len(f) - 4, 7):
        assert _warnings_of(f[i:i + 4], net) == []


def test_a_stray_point_gives_one_line_naming_drop_outliers(net):
    w = list(_frames_of_one_case()[:4])
    w[2] = np.vstack([w[2], [[3.0, 40.0]]])
    caught = _warnings_of(w, net)
    assert len(caught) == 2 and all(c.category is NotOneBodyWarning for c in caught)
    msg = str(caught[0].message)
    assert "\n" not in msg and "frame 2" in msg and "stray" in msg and "drop_outliers" in msg


def test_two_blobs_and_a_far_frame_are_named():
    f = _frames_of_one_case()[:4]
    two = [np.vstack([x, x[:12] + [10.0, 0.0]]) for x in f]
    assert "second blob" in window_body_problem(two)
    jump = f.copy()
    jump[3] += [8.0, 0.0]
    assert "frame 3's body is" in window_body_problem(jump)
    assert window_body_problem(f) is None


def test_require_cv2_is_the_public_way_to_opencv(monkeypatch):
    """The CLI reaches OpenCV through observe.require_cv2 (no private import); without the
    module the error is one line naming the vision extra."""
    import sys

    from tpnet_ref import observe
    from tpnet_ref.extras import MissingExtraError
    assert observe.require_cv2() is cv2
    monkeypatch.setitem(sys.modules, "cv2", None)            # import cv2 now fails
    with pytest.raises(MissingExtraError, match=r"tpnet-ref\[vision\]") as info:
        observe.require_cv2()
    assert "\n" not in str(info.value)
