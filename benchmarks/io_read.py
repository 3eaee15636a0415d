"""Read speed of the survey point-cloud readers on the real R2Sonic line (../shared/data/real).

    python benchmarks/io_read.py [path ...]
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from sonardet.io.points import read_points

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "r2sonic_sfbay.xyz.gz"


def main(paths):
    for p in paths or [DEFAULT]:
        read_points(p)  # warm-up (parser imports)
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            cloud = read_points(p)
            best = min(best, time.perf_counter() - t0)
        print(f"{Path(p).name}: {len(cloud)} points in {best:.3f} s ({len(cloud) / best / 1e6:.2f} M points/s), "
              f"{os.cpu_count()} cores")


if __name__ == "__main__":
    main(sys.argv[1:])
