"""Scene simulation speed and density, and what swath culling and at-rest physics save.

For N scenes of a config: seconds per scene (per stage), points per scene, points per m^2, rays per
second of the scan stage. On the first scene it also reruns (a) the scan without swath culling and
(b) the physics without island sleeping, in the same run, and reports the time each saves.

    python benchmarks/simulate.py [--config config/config.yaml] [--scenes 5] [--json out.json]
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import time
from pathlib import Path

import numpy as np

from sonardet.config import read_config
from sonardet.objects import build_object
from sonardet.objects import object_info
from sonardet.sim.dataset import scene_ids
from sonardet.sim.scene import simulate_scene


def objects_of(cfg):
    out = {}
    for c in cfg["classes"]:
        m = build_object(c, cfg["objects"])
        out[c] = object_info(m, cfg["objects"]["density_kg_m3"])
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--scenes", type=int, default=5)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    cfg = read_config(args.config)
    objs = objects_of(cfg)
    rows = []
    for sid in scene_ids(args.scenes):
        t0 = time.perf_counter()
        sc = simulate_scene(sid, cfg, objs)
        total = time.perf_counter() - t0
        m = sc.meta
        rows.append({"scene": sid, "total_s": total, **m["timings_s"], "points": m["stats"]["n_points"],
                     "points_per_m2": m["stats"]["points_per_m2"], "rays": m["stats"]["n_rays"],
                     "rays_per_s": m["stats"]["n_rays"] / m["timings_s"]["scan_s"],
                     "objects": len(m["objects"]), "direction": m["survey"]["direction"],
                     "physics_steps": m["physics"]["n_steps"], "physics_step_s": m["timings_s"].get("physics_step_s")})
        r = rows[-1]
        print(f"{sid}: {total:6.2f} s (seabed {r['seabed_s']:.2f}, layout {r['layout_s']:.2f}, physics "
              f"{r['physics_s']:.2f}, scan {r['scan_s']:.2f}); {r['points']} points, {r['points_per_m2']:.0f}/m^2, "
              f"{r['rays_per_s'] / 1e6:.2f} M rays/s, survey {r['direction']}")
    # Naive variants of the first scene whose survey runs in both directions (or the first scene).
    sid = next((r["scene"] for r in rows if r["direction"] == "xy"), rows[0]["scene"])
    culled = simulate_scene(sid, cfg, objs, cull=True).meta
    naive = simulate_scene(sid, cfg, objs, cull=False).meta
    nosleep_cfg = copy.deepcopy(cfg)
    nosleep_cfg["scenes"]["physics"]["sleep"] = False
    nosleep = simulate_scene(sid, nosleep_cfg, objs).meta
    summary = {
        "cores": os.cpu_count(), "config": str(args.config), "scenes": len(rows),
        "mean_s_per_scene": float(np.mean([r["total_s"] for r in rows])),
        "mean_points": float(np.mean([r["points"] for r in rows])),
        "mean_points_per_m2": float(np.mean([r["points_per_m2"] for r in rows])),
        "mean_rays_per_s": float(np.mean([r["rays_per_s"] for r in rows])),
        "cull_scene": sid,
        "scan_culled_s": culled["timings_s"]["scan_s"], "scan_naive_s": naive["timings_s"]["scan_s"],
        "triangles_culled": culled["stats"]["triangles_cast"], "triangles_naive": naive["stats"]["triangles_cast"],
        "physics_sleep_step_s": culled["timings_s"]["physics_step_s"], "physics_nosleep_step_s": nosleep["timings_s"]["physics_step_s"],
        "same_points_with_and_without_culling": culled["stats"]["n_points"] == naive["stats"]["n_points"],
    }
    print(f"\n{summary['scenes']} scenes, {summary['cores']} cores: {summary['mean_s_per_scene']:.2f} s/scene, "
          f"{summary['mean_points']:.0f} points/scene, {summary['mean_points_per_m2']:.0f} points/m^2, "
          f"{summary['mean_rays_per_s'] / 1e6:.2f} M rays/s in the scan stage")
    print(f"swath culling ({sid}): scan {summary['scan_naive_s']:.2f} s -> {summary['scan_culled_s']:.2f} s "
          f"(triangles cast against, summed over lines: {summary['triangles_naive']} -> {summary['triangles_culled']}); "
          f"identical point count: {summary['same_points_with_and_without_culling']}")
    print(f"physics at rest ({sid}): stepping {summary['physics_nosleep_step_s']:.2f} s without sleeping -> "
          f"{summary['physics_sleep_step_s']:.2f} s with sleeping")
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": summary, "scenes": rows}, indent=1))


if __name__ == "__main__":
    main()
