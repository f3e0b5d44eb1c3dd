"""One frame slot as the camera captures it: gain, motion blur and interlacing, then the sensor.

Motion blur and the second field come from the image motion of each pixel, not from more
renders. The ray cast of the frame already gives every pixel's wall point; projecting it into the
neighbouring frames' poses gives its image velocity V (pixels per frame, a central difference).
The wall's texture at a time offset tau (in frames) is then the albedo resampled at u - tau * V(u)
(cv2.remap), while the LED light, which rides with the camera, stays where it is; exact where the
wall is smooth, off only at depth edges, tee openings and the image border. A single blur kernel
would not do: a camera looking along a pipe sees the wall stream radially out of the image
centre, so the direction and length of the blur change across the image. Rendering sub-frames
would be exact but costs a full ray cast and lighting each (120-190 ms at 640x480), several per
frame for a visible blur, where the motion field costs about 40 ms once and each resampling 2-3 ms.

- blur: the albedo averaged over k samples of tau spread over the shutter's open time, centred
  on the frame's pose (k grows with the blur length, one sample per pixel of blur, up to 16);
- interlacing: even rows (the top field) at tau = -1/4, odd rows at tau = +1/4: two fields half a
  frame apart whose mean time is the frame's pose, each blurred over its own shutter time;
- gain scales the radiance before the sensor, so it saturates and quantises as a real camera does.
"""

from __future__ import annotations

import cv2
import numpy as np

from pipemap.sim.effects import CameraEffects
from pipemap.sim.render import Renderer

MAX_BLUR_SAMPLES = 16


class Capture:
    """Renders frame slots of a trajectory (`rotations` (n, 3, 3), `positions` (n, 3)) with `effects`."""

    def __init__(self, renderer: Renderer, rotations: np.ndarray, positions: np.ndarray, effects: CameraEffects,
                 gains: np.ndarray):
        self.renderer = renderer
        self.R = np.asarray(rotations, float)
        self.t = np.asarray(positions, float)
        self.effects = effects
        self.gains = np.asarray(gains, float)
        H, W = renderer.camera.height, renderer.camera.width
        self.grid = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))

    def image(self, j: int, rng: np.random.Generator) -> np.ndarray:
        """uint8 frame of slot j (noise from `rng`); the exposure must already be fixed."""
        shading = self.renderer.shading(self.R[j], self.t[j])
        fx = self.effects
        V = self.velocity(j, shading.points, shading.hits.hit) if fx.shutter > 0 or fx.interlace else None
        rad = shading.radiance() if V is None else shading.radiance(self.over_time(shading.albedo_image(), V))
        if self.gains[j] != 1.0:
            rad = rad * np.float32(self.gains[j])
        return self.renderer.expose(rad, rng)

    def velocity(self, j: int, P: np.ndarray, hit: np.ndarray) -> np.ndarray | None:
        """(H, W, 2) float32 image velocity in pixels per frame (0 where no wall is seen), or None
        when the trajectory has a single pose. The motion field is smooth, so it is computed on
        every second pixel in each direction and interpolated (a quarter of the projections)."""
        n = len(self.t)
        a, b = max(j - 1, 0), min(j + 1, n - 1)
        if a == b:
            return None
        cam = self.renderer.camera
        H, W = cam.height, cam.width
        index = self.renderer.pixels.index
        pick = hit & (index // W % 2 == 0) & (index % W % 2 == 0)
        X = (self.R[j] @ P[:, pick].astype(np.float64)) + self.t[j][:, None]  # (3, M) world points
        uv = []
        ok = np.ones(X.shape[1], bool)
        for k in (a, b):
            Pk = (self.R[k].T @ (X - self.t[k][:, None])).T
            u, _ = cam.project(Pk)
            ok &= np.all(np.isfinite(u), axis=-1) & (cam.colatitude(Pk) <= cam.max_theta)
            uv.append(u)
        vel = (uv[1] - uv[0]) / float(b - a)
        h2, w2 = (H + 1) // 2, (W + 1) // 2
        coarse = np.zeros((h2 * w2, 2), np.float32)
        at = index[pick][ok]
        coarse[at // W // 2 * w2 + at % W // 2] = vel[ok]
        gx, gy = self.grid
        return cv2.remap(coarse.reshape(h2, w2, 2), gx * 0.5, gy * 0.5, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)

    def over_time(self, albedo: np.ndarray, V: np.ndarray) -> np.ndarray:
        """The wall's albedo as the shutter integrates it: blurred, and/or two fields."""
        fx = self.effects
        if fx.shutter > 0:
            speed = np.hypot(V[..., 0], V[..., 1])
            length = fx.shutter * float(np.percentile(speed, 99))
            k = int(np.clip(np.ceil(length), 1, MAX_BLUR_SAMPLES))
        else:
            k = 1
        offsets = fx.shutter * ((np.arange(k) + 0.5) / k - 0.5)
        if not fx.interlace:
            return self._sample(albedo, V, offsets)
        out = self._sample(albedo, V, offsets - 0.25)
        out[1::2] = self._sample(albedo, V, offsets + 0.25)[1::2]
        return out

    def _sample(self, img: np.ndarray, V: np.ndarray, taus) -> np.ndarray:
        gx, gy = self.grid
        acc = np.zeros_like(img)
        for tau in taus:
            if abs(tau) < 1e-9:
                acc += img
                continue
            tau = np.float32(tau)
            acc += cv2.remap(img, gx - tau * V[..., 0], gy - tau * V[..., 1], cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REPLICATE)
        acc *= np.float32(1.0 / len(taus))
        return acc
