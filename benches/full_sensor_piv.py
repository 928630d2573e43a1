"""Full-sensor PIV timing: one synthetic 8864 x 5288 pair through the paper's passes.

Run: ``python benches/full_sensor_piv.py``. Renders the pair with
``rspiv.synth.particle_pair`` (smooth field u = 4 + 1.5 sin(2 pi y / 1024), v = 0.8 cos(2 pi x /
2048) px), then times ``rspiv.piv`` with passes 64x64 -> 32x32 -> 32x8 (50 % overlap) twice and
prints the process's peak RSS.
"""

import resource
import time

import numpy as np
import rspiv
from rspiv.synth import particle_pair


def main() -> None:
    t = time.perf_counter()
    a, b = particle_pair(
        (5288, 8864),
        lambda x, y: (4 + 1.5 * np.sin(2 * np.pi * y / 1024), 0.8 * np.cos(2 * np.pi * x / 2048)),
        seed=1,
    )[:2]
    print(f"render {time.perf_counter() - t:.2f} s")
    for _ in range(2):
        t = time.perf_counter()
        f = rspiv.piv(a, b, passes=[(64, 64), (32, 32), (32, 8)], overlap=0.5)
        print(f"piv 8864x5288 64->32->32x8: {time.perf_counter() - t:.2f} s, {f.u.size} vectors")
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
