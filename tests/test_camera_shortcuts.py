"""The warp renderer's speed shortcuts change no pixel: frames drawn with them equal, bit for bit, the frames drawn
without them (image, z-depth, surface ids) on poses that see the wall, its ends, the roof, the ground up to the
horizon and the background."""

from __future__ import annotations

import numpy as np
import pytest

from sim.camera.scene import Scene
from sim.camera.warp_render import WarpRenderer
from tests.test_camera_warp_render import CAM, FRAME, POSES, H, L


def _frames():
    r = WarpRenderer(Scene.build(L, H, seed=0), FRAME, CAM, noise=False, blur=False)
    return {name: r.render(pose) for name, pose in POSES.items()}


@pytest.fixture(scope="module")
def with_shortcuts():
    return _frames()


def test_shortcuts_change_no_pixel(with_shortcuts, monkeypatch):
    """Without them: every warp replicates the patch's edge texels (OpenCV's border rule for samples outside it;
    the shortcut uses the cheaper constant border only where every kept pixel samples inside the patch, not for
    the far ground's window-cut patch up to the horizon), and the first face drawn goes through the depth test."""
    warp = WarpRenderer._warp

    def replicate(self, patch4, Hm, size, dst=None, inside=False):
        return warp(self, patch4, Hm, size, dst=dst, inside=False)

    monkeypatch.setattr(WarpRenderer, "_warp", replicate)
    monkeypatch.setattr(WarpRenderer, "_in_front", lambda self, uv, g: False)
    without = _frames()
    for name, got in with_shortcuts.items():
        ref = without[name]
        assert np.array_equal(got.image, ref.image), name
        assert np.array_equal(got.depth, ref.depth), name
        assert np.array_equal(got.surface, ref.surface), name


def test_the_shortcuts_are_taken(with_shortcuts, monkeypatch):
    """The shortcuts run on these poses (else the comparison above would be empty): the constant border on the
    wall face-on, the first face without the depth test where the wall's end or the roof line is in view."""
    taken = {"inside": 0, "front": 0}
    warp, front = WarpRenderer._warp, WarpRenderer._in_front

    def counted_warp(self, patch4, Hm, size, dst=None, inside=False):
        taken["inside"] += inside
        return warp(self, patch4, Hm, size, dst=dst, inside=inside)

    def counted_front(self, uv, g):
        ok = front(self, uv, g)
        taken["front"] += ok
        return ok

    monkeypatch.setattr(WarpRenderer, "_warp", counted_warp)
    monkeypatch.setattr(WarpRenderer, "_in_front", counted_front)
    _frames()
    assert taken["inside"] >= 3 and taken["front"] >= 2, taken
