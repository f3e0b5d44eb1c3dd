"""Burned-in text and other pixels that do not move with the wall are found from the frames alone."""

from __future__ import annotations

import cv2
import numpy as np

from pipemap.frontend.static_mask import find_static_mask

H, W = 240, 320


def _frames(n: int, step_px: float, seed: int = 0, text: bool = True):
    """A random wall texture sliding right by step_px a frame, under a fixed text overlay whose last digits
    change every frame (a distance counter)."""
    rng = np.random.default_rng(seed)
    wall = cv2.GaussianBlur(rng.uniform(0, 255, (H, W * 4)).astype(np.float32), (0, 0), 1.5)
    wall = 60 + 120 * (wall - wall.min()) / np.ptp(wall)
    for k in range(n):
        x = int(round(k * step_px))
        img = np.ascontiguousarray(wall[:, x:x + W])
        if text:
            for colour, thick in ((0, 4), (255, 1)):
                cv2.putText(img, f"MH12 {1.23 + 0.01 * k:6.2f} m", (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.7, colour,
                            thick, cv2.LINE_8)
        yield img


def _text_box() -> np.ndarray:
    box = np.zeros((H, W), bool)
    box[8:38, 8:230] = True
    return box


def test_text_over_a_moving_wall_is_masked_and_little_else():
    inside = np.ones((H, W), np.uint8)
    m = find_static_mask(_frames(40, 7.0), inside, lighting_sigma_px=4.0, grow_px=4)
    assert m is not None and m.frames == 40
    layers = []
    for k in range(40):  # the text's pixels in every frame: what never changes
        layer = np.zeros((H, W), np.uint8)
        cv2.putText(layer, f"MH12 {1.23 + 0.01 * k:6.2f} m", (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.7, 255, 4,
                    cv2.LINE_8)
        layers.append(layer > 0)
    static_text = np.logical_and.reduce(layers)
    assert (~m.usable & static_text).sum() / static_text.sum() > 0.99
    outside = ~cv2.dilate(_text_box().astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)
    assert (~m.usable & outside).mean() < 0.01
    assert m.masked_fraction < 0.12 and any(x < 40 and y < 40 for x, y, *_ in m.regions)


def test_a_wall_without_overlay_is_not_masked():
    m = find_static_mask(_frames(40, 7.0, text=False), np.ones((H, W), np.uint8), 4.0, grow_px=4)
    assert m.masked_fraction < 0.01


def test_too_few_frames_tell_nothing():
    assert find_static_mask(_frames(5, 7.0), np.ones((H, W), np.uint8), 4.0) is None


def _ringed(frames, radius: float = 70.0, step: float = 0.92):
    """`frames` whose rim beyond `radius` px from the image centre is dim and smoothed by the codec, the light
    falling off by a step where it starts: a quantised ramp, which stays put like an overlay but is wall."""
    yy, xx = np.mgrid[0:H, 0:W]
    r = np.hypot(xx - W / 2, yy - H / 2)
    smooth, outer = r > radius - 12, r > radius
    for img in frames:
        img = img.copy()
        img[smooth] = 120 + 0.05 * (img[smooth] - 120)
        img[outer] *= step
        yield img


def test_a_ring_of_the_light_is_kept_out_of_features_but_not_out_of_view():
    yy, xx = np.mgrid[0:H, 0:W]
    ring = np.abs(np.hypot(xx - W / 2, yy - H / 2) - 70.0) < 2
    ring &= ~cv2.dilate(_text_box().astype(np.uint8), np.ones((25, 25), np.uint8)).astype(bool)
    m = find_static_mask(_ringed(_frames(40, 7.0)), np.ones((H, W), np.uint8), 4.0, grow_px=4,
                         centre=(W / 2, H / 2))
    assert m.rings >= 1
    assert (~m.usable[ring]).mean() > 0.9  # features stay off the ring
    assert m.view[ring].mean() > 0.99  # classification and maps see the wall there
    assert len(m.regions) >= 1 and all(y < 40 for _, y, *_ in m.regions)  # only the text is an overlay
    assert not m.view[_text_box()].all()


def _unlit_end(frames, seed: int = 1):
    """The frames with the dark far end of a straight pipe at the centre, as a codec leaves it: the light falling
    off towards the centre, and there grey levels of a few units in 8 x 8 blocks that stay where they are."""
    rng = np.random.default_rng(seed)
    blocks = np.kron(rng.integers(1, 9, (8, 8)), np.ones((8, 8))).astype(np.float32)  # 64 x 64 px
    v, u = np.mgrid[0:H, 0:W]
    light = np.clip((np.hypot(u - 160, v - 120) - 24.0) / 70.0, 0.02, 1.0).astype(np.float32)
    for img in frames:
        img = img * light
        img[88:152, 128:192] = np.where(light[88:152, 128:192] <= 0.1, blocks, img[88:152, 128:192])
        yield img


def test_the_unlit_far_end_is_kept_from_features_but_not_from_view():
    """The unlit far end's static blocks are no overlay: masked from view, they hid it from the classification,
    and a straight pipe as MJPEG became a junction from end to end. The bright text stays an overlay."""
    inside = np.ones((H, W), np.uint8)
    m = find_static_mask(_unlit_end(_frames(40, 7.0)), inside, lighting_sigma_px=4.0, grow_px=4)
    end = np.zeros((H, W), bool)
    end[108:132, 148:172] = True
    assert m.unlit == 1 and m.to_dict()["unlit_regions"] == 1
    assert not m.usable[end].any()  # no feature on it
    assert m.view[end].all()  # the classification and the maps see it
    assert not m.view[_text_box()].all() and any(x < 40 and y < 40 for x, y, *_ in m.regions)
    assert all(not (120 <= x <= 200 and 80 <= y <= 160) for x, y, *_ in m.regions)
    off = find_static_mask(_unlit_end(_frames(40, 7.0)), inside, lighting_sigma_px=4.0, grow_px=4, dark_share=None)
    assert off.unlit == 0 and not off.view[end].any()  # as before: taken for an overlay
