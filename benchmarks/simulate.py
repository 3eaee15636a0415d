"""Scene simulation speed and density, and what swath culling, at-rest physics and settled-layout reuse save.

For N scenes of a config: seconds per scene (per stage), points per scene, points per m^2, rays per
second of the scan stage. On the first scene it also reruns (a) the scan without swath culling and
(b) the physics without island sleeping, in the same run, and reports the time each saves. For every
scene it then makes the realism test variant (`realism_test`: the sensor's realism profile, burial)
twice, settling again and from the scene's settled layout as the workflow does, and reports the
seconds of each and whether the two are the same scene (soundings and annotations, byte for byte).

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
from sonardet.config.realism import realism_test_config
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
    rows, settled = [], {}
    for sid in scene_ids(args.scenes):
        t0 = time.perf_counter()
        sc = simulate_scene(sid, cfg, objs)
        total = time.perf_counter() - t0
        settled[sid] = json.loads(json.dumps(sc.settled))  # through JSON, as the workflow's file
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
    summary.update(realism_reuse(cfg, objs, settled))
    print(f"realism variants ({summary['realism_scenes']} scenes): {summary['realism_settle_s']:.2f} s/scene settling "
          f"again -> {summary['realism_reuse_s']:.2f} s/scene from the settled layout; the same scenes: "
          f"{summary['realism_same_scenes']}")
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": summary, "scenes": rows}, indent=1))


def realism_reuse(cfg: dict, objs: dict, settled: dict) -> dict:
    """Seconds per realism variant (`realism_test_config`) of each scene, settled again and from its
    settled layout, and whether every pair is the same scene byte for byte (timings aside)."""
    rcfg = realism_test_config(cfg)
    times = {"settle": [], "reuse": []}
    same = True
    for sid, layout in settled.items():
        t0 = time.perf_counter()
        a = simulate_scene(sid, rcfg, objs)
        times["settle"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        b = simulate_scene(sid, rcfg, objs, settled=layout)
        times["reuse"].append(time.perf_counter() - t0)
        same &= all(getattr(a, k).tobytes() == getattr(b, k).tobytes() for k in ("xyz", "ping", "beam", "line", "label"))
        ma, mb = ({k: v for k, v in m.items() if k != "timings_s"} for m in (a.meta, b.meta))
        same &= json.dumps(ma) == json.dumps(mb)
    return {"realism_scenes": len(settled), "realism_settle_s": float(np.mean(times["settle"])),
            "realism_reuse_s": float(np.mean(times["reuse"])), "realism_same_scenes": bool(same)}


if __name__ == "__main__":
    main()
