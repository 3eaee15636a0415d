"""Scenes a benchmark makes with the project's simulator, cached as npz + json under a folder.

The benchmarks that need scenes the workflow does not make (dumped piles, object-count sweeps) share
this: a scene is simulated only when its two files are missing, so a rerun reads the cache.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from sonardet.io.scenes import write_scene
from sonardet.sim.scene import simulate_scene


def make_scenes(cfg: dict, objects: dict, ids: list[str], out: Path,
                describe: Callable[[dict], str] | None = None) -> None:
    """Simulate the scenes `ids` not yet under `out` (npz + json) with `cfg`; one progress line each.

    `describe(meta)` adds a note about the scene's JSON to its progress line (e.g. its pile sizes).
    """
    out.mkdir(parents=True, exist_ok=True)
    for sid in ids:
        npz, js = out / f"{sid}.npz", out / f"{sid}.json"
        if npz.is_file() and js.is_file():
            continue
        t = time.perf_counter()
        scene = simulate_scene(sid, cfg, objects)
        write_scene(scene, npz, js)
        note = f", {describe(scene.meta)}" if describe else ""
        print(f"  simulated {sid}: {len(scene.meta['objects'])} objects{note}, {time.perf_counter() - t:.0f} s",
              flush=True)
