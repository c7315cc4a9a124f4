"""The held-out acceptance checks of a depth model, as figures, for several models in one run (issue 13).

Prints, per model, what ``tests/test_depth_model.py`` and ``tests/test_depth_real_mask.py`` assert, with the model
in place of the one each test loads: the mask error on the 12 held-out seed-300 demo frames (bound < 5 %, no frame
with wall dropped, the true facade nearer), the DJI wall photos kept (640 px fixtures >= 85 % with all of the plain
left 80 %; full-size >= 98 %), CMP b0283's windows and facade kept (>= 95 %), and the all-background frame of three
real-texture passes (must be dropped). A model that is to become the default must pass every line (docs/DEPTH.md,
"Near/far mask loss"). The tests stay the judge; this prints the numbers where a test only says pass or fail.

Usage: python bench/mask_loss_acceptance.py MODEL [MODEL ...]   (a shipped name, sim / real-nc, or an .onnx file)
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import cv2
import numpy as np
from checkout import use_checkout_shared_data
from PIL import Image

from companion.depth.masker import Masker
from companion.depth.training.realdata import facade_mask, list_real_photos, load_image
from companion.records import Frame, TaggedFrame
from evaluation.depth.evaluate import evaluate_recording
from sim.camera.photo_passes import RECIPES, build_pass
from sim.camera.photo_scene import PhotoPassRenderer
from sim.camera.recording import generate_recording

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "depth_fixtures"
CMP_WINDOW = 3
PASSES = ("ornate-entry", "cmp-balconies", "dji-plain-wall")


def _roi(masker: Masker, image: np.ndarray):
    return masker.mask(TaggedFrame(Frame(index=0, capture_time_s=0.0, image=image), pose=None))


def acceptance(masker: Masker, recording: Path, backgrounds: dict[str, np.ndarray]) -> tuple[dict, bool]:
    """The figures of both test files for one model, and whether every check passes."""
    out: dict = {}
    s = evaluate_recording(recording, masker).summary()
    out["sim300_error_mean_pct"] = round(100 * s["error_mean"], 2)
    out["sim300_dropped_with_facade"] = s["dropped_with_facade"]
    nearer = s["true_roi_nearer_fraction"]
    ok = s["error_mean"] < 0.05 and s["dropped_with_facade"] == 0 and (nearer == 1.0 or np.isnan(nearer))
    for name in ("DJI_0977_rgb_640.jpg", "DJI_0981_rgb_640.jpg"):
        image = cv2.imread(str(FIXTURES / name))
        masked, roi = _roi(masker, image)
        w, h = int(0.8 * image.shape[1]), image.shape[0]
        plain = 0.0 if masked is None else np.count_nonzero(masked.mask[:, :w]) / (h * w)
        out[f"{name}_kept_pct / plain_left_kept_pct"] = (round(100 * roi.roi_fraction, 1), round(100 * plain, 1))
        ok &= (masked is not None and roi.roi_fraction >= 0.85 and plain >= 0.99
               and masked.mask[h // 2 :, :w].min() == 255)
    held = {p.image.name: p for p in list_real_photos(use_checkout_shared_data(), split="heldout")}
    for name in ("DJI_0977_rgb.JPG", "DJI_0981_rgb.JPG"):
        _, roi = _roi(masker, load_image(held[name]))
        out[f"{name}_kept_pct"] = round(100 * roi.roi_fraction, 1)
        ok &= not roi.empty and roi.roi_fraction >= 0.98
    photo = held["cmp_b0283.jpg"]
    _, roi = _roi(masker, load_image(photo))
    with Image.open(photo.label) as im:
        windows = np.array(im) == CMP_WINDOW
    kept = roi.mask > 0
    win, fac = float(kept[windows].mean()), float(kept[facade_mask(photo) > 0].mean())
    out["cmp_b0283_windows / facade_kept_pct"] = (round(100 * win, 1), round(100 * fac, 1))
    ok &= win >= 0.95 and fac >= 0.95
    for name, image in backgrounds.items():
        _, roi = _roi(masker, image)
        out[f"far_background_{name}"] = "dropped" if roi.empty else f"kept {100 * roi.roi_fraction:.1f} %"
        ok &= roi.empty
    return out, bool(ok)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+", help="shipped model names (sim, real-nc) or .onnx files")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        # the held-out recording of tests/test_depth_model.py: seed 300, 12 frames over the whole scan
        recording = generate_recording(ROOT / "missions" / "demo-facade.yaml", Path(tmp) / "demo_seed300", seed=300,
                                       stride=211, max_frames=12)
        backgrounds = {}
        for name in PASSES:
            renderer = PhotoPassRenderer(build_pass(RECIPES[name], root=use_checkout_shared_data(),
                                                    frames=12, background_frames=2))
            backgrounds[name] = renderer.render(len(renderer) - 1).image
        for model in args.models:
            figures, ok = acceptance(Masker(model, threads=1), recording, backgrounds)
            print(f"{model}: {'passes both test files' if ok else 'FAILS'} {json.dumps(figures)}", flush=True)


if __name__ == "__main__":
    main()
