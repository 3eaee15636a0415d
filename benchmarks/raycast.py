"""Throughput of the MBES sensor model against a raw Embree cast of the same rays.

Builds a ~100k-triangle terrain heightfield (40 x 40 m), a survey line of 1024-beam pings
(about 1 M rays), then times (a) the raw Embree cast of the prebuilt rays through Open3D's
RaycastingScene and (b) the full sensor model `sonardet.sim.mbes.scan` on the same trajectory
(ray generation, cast, dropouts, noise, float64 soundings). Prints rays per second of both, their
ratio, and the core count; `--json PATH` also writes the figures.

    python benchmarks/raycast.py [--rays 1000000] [--repeat 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np
import open3d as o3d

from sonardet.sim.mbes import RaycastTarget, SensorConfig, beam_angles, build_rays, scan, straight_line


def terrain(n: int = 224, size: float = 40.0, rng=None):
    """A gently undulating heightfield mesh with 2 n^2 triangles."""
    rng = rng or np.random.default_rng(0)
    x = np.linspace(0, size, n + 1)
    xx, yy = np.meshgrid(x, x)
    zz = -11.5 + 0.2 * np.sin(xx / 3.0) * np.cos(yy / 4.0) + 0.02 * rng.standard_normal(xx.shape)
    v = np.c_[xx.ravel(), yy.ravel(), zz.ravel()]
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 1, i.ravel() + n + 2
    f = np.vstack([np.c_[a, b, d], np.c_[a, d, c]])
    return v, f


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    v, f = terrain()
    sensor = SensorConfig(n_beams=1024)
    target = RaycastTarget([(v, f)])
    n_pings = max(1, args.rays // sensor.n_beams)
    step = 40.0 / n_pings
    traj = straight_line([0, 20], [step * (n_pings - 1) + 1e-9, 20], 0.0, sensor, 11.5)
    traj.position = traj.position[:1].repeat(n_pings, 0)
    traj.position[:, 0] = np.arange(n_pings) * step
    traj.heading_rad = traj.heading_rad[:1].repeat(n_pings)
    traj.line = traj.line[:1].repeat(n_pings)
    rays = o3d.core.Tensor(build_rays(traj, beam_angles(sensor)))
    n_rays = rays.shape[0]
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
    scene.cast_rays(rays)  # build the BVH outside the timing, as scan's target has done once

    raw, model = [], []
    for r in range(args.repeat):
        t0 = time.perf_counter()
        out = scene.cast_rays(rays)
        out["t_hit"].numpy()
        raw.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        snd = scan(target, traj, sensor, np.random.default_rng(r))
        model.append(time.perf_counter() - t0)
    res = {
        "cores": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "triangles": int(len(f)),
        "rays": int(n_rays),
        "soundings": int(len(snd.xyz)),
        "raw_embree_s": min(raw),
        "sensor_model_s": min(model),
        "raw_embree_rays_per_s": n_rays / min(raw),
        "sensor_model_rays_per_s": n_rays / min(model),
    }
    res["ratio"] = res["sensor_model_rays_per_s"] / res["raw_embree_rays_per_s"]
    print(f"cores={res['cores']} triangles={res['triangles']} rays={res['rays']}")
    print(f"raw Embree cast : {res['raw_embree_s'] * 1e3:8.1f} ms  {res['raw_embree_rays_per_s'] / 1e6:6.2f} M rays/s")
    print(f"sensor model    : {res['sensor_model_s'] * 1e3:8.1f} ms  {res['sensor_model_rays_per_s'] / 1e6:6.2f} M rays/s")
    print(f"ratio (model / raw) = {res['ratio']:.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res, fh, indent=1)


if __name__ == "__main__":
    main()
