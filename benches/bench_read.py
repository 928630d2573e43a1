"""Reading a full 47 MP 16-bit frame (8864 x 5288): ``rspiv.io.read_image`` side by side with
``tifffile.imread`` on the same file, in one run.

    python benches/bench_read.py [--repeat 5] [--scale 1.0]

Files (written to a temporary folder first, not timed): a single-page uncompressed uint16 TIFF,
the same frame as page 2 of a 3-page stack, and a 12-bit frame stored in 16 bits. Times are the
best of ``--repeat`` interleaved reads (the file in the page cache, as for a campaign that has
just listed its files); the ratio is rspiv / tifffile (issue 11's target: <= 1.5).
"""

from __future__ import annotations

import argparse
import pathlib
import tempfile

import numpy as np
from bench_piv import best_of  # the one best-of-n timer of the benches


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--scale", type=float, default=1.0, help="sensor scale (1.0: 8864 x 5288)")
    args = ap.parse_args()
    import tifffile
    from rspiv.io import read_image

    h, w = int(round(5288 * args.scale)), int(round(8864 * args.scale))
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 65535, (h, w), dtype=np.uint16)
    with tempfile.TemporaryDirectory() as tmp:
        single = pathlib.Path(tmp) / "frame.tif"
        stack = pathlib.Path(tmp) / "stack.tif"
        twelve = pathlib.Path(tmp) / "frame12.tif"
        tifffile.imwrite(single, frame)
        tifffile.imwrite(stack, np.stack([frame, frame, frame]), photometric="minisblack")
        tifffile.imwrite(twelve, frame >> 4)
        cases = [
            ("single page uint16", lambda: read_image(single), lambda: tifffile.imread(single)),
            (
                "page 2 of a 3-page stack",
                lambda: read_image(stack, frame=1),
                lambda: tifffile.imread(stack, key=1),
            ),
            ("12-bit in 16", lambda: read_image(twelve), lambda: tifffile.imread(twelve)),
        ]
        for f in (c[1] for c in cases):
            f()  # warm the page cache
        print(f"{w} x {h} px uint16 ({frame.nbytes / 1e6:.0f} MB), best of {args.repeat}")
        print("| file | rspiv.io.read_image | tifffile.imread | rspiv / tifffile |")
        print("|---|---|---|---|")
        for name, ours, theirs in cases:
            a, b = [], []
            for _ in range(args.repeat):
                a.append(best_of(ours, 1)[0])
                b.append(best_of(theirs, 1)[0])
            assert np.array_equal(ours(), theirs())
            print(f"| {name} | {min(a) * 1e3:.1f} ms | {min(b) * 1e3:.1f} ms | "
                  f"{min(a) / min(b):.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
