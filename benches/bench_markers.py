"""Marker detection on the full 47 MP target, one run per marker kind, rspiv side by side with
OpenCV's SimpleBlobDetector (issue 15).

Each kind is the paper's sensor and grid (8864 x 5288 px, 13 x 7 markers, 674 px pitch, the
paper's lens) rendered by rspiv.synth with an exact answer:

- gaussian: Gaussian dots of sigma 17.3 px, bright on dark, 12 bit (the paper's target);
- disc 70: printed discs 70 px across, 1.5 px blur, 12 bit;
- disc 70 dark 8-bit: dark discs on a bright plate, 8 bit, vignetting 5x, 30 clutter blobs
  (9 x 5 markers: room off the plate for the clutter);
- disc 8: small printed discs 8 px across, 1 px blur.

rspiv is given nothing but the image (size, polarity and profile read from it); OpenCV is given
the polarity and an area range around the true dot area (its parameters must be tuned per
image). Reported: the best of ``--repeat`` wall times, the markers found within 2 px of a true
one, and the RMS centre error (px) against the truth.

Run: python benches/bench_markers.py [--repeat 3] [--kinds gaussian,disc70,...]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np
from rspiv import _rspiv
from rspiv.synth import calibration_target
from rspiv.synth.target import PAPER_OPTICS
from scipy.spatial import cKDTree

KINDS = {
    "gaussian": {},
    "disc70": {"dot": "disc", "dot_diameter_px": 70.0, "blur_px": 1.5},
    "disc70-dark-8bit": {
        "dot": "disc", "dot_diameter_px": 70.0, "blur_px": 1.5, "dark": True, "bit_depth": 8,
        "vignetting": 0.8, "clutter": 30,
        "optics": dataclasses.replace(PAPER_OPTICS, n_markers=(9, 5)),  # room for the clutter
    },  # fmt: skip
    "disc8": {"dot": "disc", "dot_diameter_px": 8.0, "blur_px": 1.0},
}


def score(found: np.ndarray, truth: np.ndarray) -> tuple[int, float]:
    if len(found) == 0:
        return 0, float("nan")
    d, _ = cKDTree(found).query(truth)
    ok = d < 2.0
    return int(ok.sum()), float(np.sqrt(np.mean(d[ok] ** 2))) if ok.any() else float("nan")


def opencv_detect(img: np.ndarray, dark: bool, area: float) -> np.ndarray:
    import cv2

    scale = 255.0 / max(1, int(img.max()))
    u8 = img if img.dtype == np.uint8 else (img.astype(np.float32) * scale).astype(np.uint8)
    p = cv2.SimpleBlobDetector_Params()
    p.filterByColor = True
    p.blobColor = 0 if dark else 255
    p.filterByArea = True
    p.minArea, p.maxArea = 0.3 * area, 3.0 * area
    p.filterByCircularity = p.filterByInertia = p.filterByConvexity = False
    kp = cv2.SimpleBlobDetector_create(p).detect(u8)
    return np.array([k.pt for k in kp], dtype=np.float64).reshape(-1, 2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--kinds", default=",".join(KINDS))
    args = ap.parse_args()
    try:
        import cv2  # noqa: F401

        have_cv = True
    except ImportError:
        have_cv = False
    print("kind | rspiv s | found | RMS px | profile, polarity | OpenCV s | found | RMS px | ratio")
    for name in args.kinds.split(","):
        kw = KINDS[name]
        t = calibration_target(scale=1.0, seed=0, **kw)
        n = len(t.markers_px)
        best, det = np.inf, None
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            det = _rspiv.detect_markers(t.image)
            best = min(best, time.perf_counter() - t0)
        nf, rms = score(det["image_px"], t.markers_px)
        line = (
            f"{name} | {best:.3f} | {nf}/{n} | {rms:.4f} | {det['profile']}, "
            f"{'dark' if det['dark'] else 'bright'}"
        )
        if have_cv:
            if kw.get("dot") == "disc":
                area = np.pi * (0.5 * kw["dot_diameter_px"]) ** 2
            else:
                area = np.pi * (2.0 * t.extra["dot_sigma_px"]) ** 2
            cbest, pts = np.inf, None
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                pts = opencv_detect(t.image, bool(kw.get("dark", False)), area)
                cbest = min(cbest, time.perf_counter() - t0)
            cf, crms = score(pts, t.markers_px)
            line += f" | {cbest:.3f} | {cf}/{n} | {crms:.4f} | {cbest / best:.2f}"
        print(line, flush=True)


if __name__ == "__main__":
    main()
