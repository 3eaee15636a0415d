"""Benchmark: settling a full 40 x 40 m scene with and without MuJoCo island sleeping.

Default scene (``--scene tetrapods``): the default seabed (sonardet.sim.seabed.make_seabed), 55
tetrapod-like bodies (4 tapered legs, one convex part per leg; alternating 2.08 m / 6 t and
1.42 m / 2 t like the tetrapod_b / tetrapod_s classes), 46 scattered in random orientations and 9
small ones spawned as a pile in 3 layers, plus 20 dynamic rocks (0.2-1.5 m).
``--scene catalog``: 60 objects of the four real classes (sonardet.objects.meshes.build_object with
config/config.yaml: rings of 32 convex parts, cones of 16, tetrapods of 5) plus 20 dynamic rocks.

The same scene is settled with ``sleep=True`` (bodies at rest leave the pipeline) and ``sleep=False``
(every body simulated every step until all are at rest; same rest criterion). Prints wall time,
steps, simulated time and the saving. MuJoCo runs single-threaded (one core).

Run: ``python benchmarks/physics.py [--scene tetrapods|catalog] [--seed N] [--repeat N]``.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import trimesh

from sonardet.geometry import quat_to_matrix, random_quat
from sonardet.sim.physics import RigidBody, place_above, settle
from sonardet.sim.rocks import make_rocks, rock_mass_kg
from sonardet.sim.seabed import make_seabed


def tetrapod_like_parts(height_m: float, sections: int = 24, root_ratio: float = 0.28, taper: float = 0.6):
    """Four tapered legs (frustum vertex arrays) at tetrahedral angles, base at z = 0, one leg up."""
    s = np.sqrt(8.0 / 9.0)
    ang = np.deg2rad([0.0, 120.0, 240.0])
    dirs = np.vstack([[0.0, 0.0, 1.0], np.stack([s * np.cos(ang), s * np.sin(ang), np.full(3, -1.0 / 3.0)], 1)])
    leg = height_m / (4.0 / 3.0 + taper * root_ratio * s)
    r0 = root_ratio * leg
    parts = []
    for d in dirs:
        prof = np.array([[0.0, 0.0], [r0, 0.0], [taper * r0, leg], [0.0, leg], [0.0, 0.0]])
        m = trimesh.creation.revolve(prof, sections=sections)
        m.apply_transform(trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d))
        parts.append(np.asarray(m.vertices))
    zmin = min(p[:, 2].min() for p in parts)
    return [p - [0.0, 0.0, zmin] for p in parts]


def _catalog_classes():
    """(name, convex parts, mass kg, reach m, upright) of the four real classes at the default config."""
    from sonardet.config import read_config
    from sonardet.objects.meshes import build_object

    here = os.path.dirname(os.path.abspath(__file__))
    cfg = read_config(os.path.join(here, "..", "config", "config.yaml"))["objects"]
    out = []
    for cls in ("reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"):
        m = build_object(cls, cfg)
        ext = m.mesh.extents
        upright = cls.startswith("reef")
        reach = 0.5 * float(np.hypot(ext[0], ext[1])) if upright else 0.75 * float(ext[2])
        out.append((cls, m.convex_parts, float(m.mesh.volume) * cfg["density_kg_m3"], reach, upright))
    return out


def build_scene(seed: int, kind: str = "tetrapods", sections: int = 24, n_rocks: int = 20):
    """(heightfield, bodies) of the benchmark scene, deterministic in seed."""
    rng = np.random.default_rng(seed)
    hf = make_seabed(rng=rng)
    bodies, discs = [], []  # discs: (x, y, r) footprints already used

    def free_spot(r, lo=3.0, hi=37.0):
        for _ in range(10000):
            p = rng.uniform(lo, hi, 2)
            if all(np.hypot(p[0] - x, p[1] - y) > r + rr + 0.2 for x, y, rr in discs):
                discs.append((p[0], p[1], r))
                return p
        raise RuntimeError("no free spot")

    def spawn(name, parts, mass, xy, z_clear=0.15, above=None, upright=False):
        if upright:  # reef elements are lowered on their base, at a random yaw
            a = rng.uniform(0, 2 * np.pi)
            q = np.array([np.cos(a / 2), 0.0, 0.0, np.sin(a / 2)])
        else:
            q = random_quat(rng)
        pos = place_above(parts, q, xy, hf, clearance_m=z_clear)
        v = np.vstack(parts) @ quat_to_matrix(q).T
        if above is not None:  # stack: lowest point above the given elevation
            pos[2] = max(pos[2], above - v[:, 2].min() + z_clear)
        return RigidBody(name, parts, mass, pos, q), v[:, 2].max() + pos[2]

    if kind == "tetrapods":
        big = tetrapod_like_parts(2.08, sections)
        small = tetrapod_like_parts(1.42, sections)
        n_pile = 9
        for i in range(55 - n_pile):
            parts, mass, h = (big, 6000.0, 2.08) if i % 2 == 0 else (small, 2000.0, 1.42)
            bodies.append(spawn(f"tetra{i}", parts, mass, free_spot(0.75 * h))[0])
        # pile of small tetrapods, 3 layers of 3: each layer spawned above the previous layer's top,
        # its members 1.3 m from the pile axis (2.25 m apart: clear of each other in any orientation)
        pile_xy = free_spot(2.5)
        k, top = 0, None
        while k < n_pile:
            layer_top, phase = -np.inf, rng.uniform(0, 2 * np.pi)
            for j in range(min(3, n_pile - k)):
                a = phase + 2 * np.pi * j / 3
                b, t = spawn(f"pile{k}", small, 2000.0, pile_xy + 1.3 * np.array([np.cos(a), np.sin(a)]), above=top)
                bodies.append(b)
                layer_top = max(layer_top, t)
                k += 1
            top = layer_top
    elif kind == "catalog":
        classes = _catalog_classes()
        for i in range(60):
            cls, parts, mass, reach, upright = classes[i % len(classes)]
            bodies.append(spawn(f"{cls}{i}", parts, mass, free_spot(reach), z_clear=0.1, upright=upright)[0])
    else:
        raise ValueError(f"unknown scene kind {kind!r}")
    for i, rock in enumerate(make_rocks(n_rocks, rng)):
        parts = [np.asarray(rock.vertices) - np.asarray(rock.vertices).mean(0)]  # spin about its middle
        xy = free_spot(0.6 * float(np.max(rock.extents)), 1.5, 38.5)
        bodies.append(spawn(f"rock{i}", parts, rock_mass_kg(rock), xy, z_clear=0.05)[0])
    return hf, bodies


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=["tetrapods", "catalog"], default="tetrapods")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--sections", type=int, default=24, help="facets around each tetrapod-like leg")
    ap.add_argument("--repeat", type=int, default=1, help="runs per variant; the fastest is reported")
    ap.add_argument("--dt", type=float, default=0.004)
    args = ap.parse_args(argv)
    hf, bodies = build_scene(args.seed, args.scene, args.sections)
    n_parts = sum(len(b.convex_parts) for b in bodies)
    print(f"# scene '{args.scene}' seed {args.seed}: {len(bodies)} bodies, {n_parts} convex parts, seabed "
          f"{hf.nx}x{hf.ny} nodes; {platform.machine()}, {os.cpu_count()} cores visible, MuJoCo single-threaded, "
          f"load average {os.getloadavg()[0]:.1f}")
    rows = {}
    for sleep in (True, False):
        runs = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            res = settle(bodies, hf, rng=np.random.default_rng(0), sleep=sleep, dt_s=args.dt)
            runs.append((time.perf_counter() - t0, res))
        wall, res = min(runs, key=lambda r: r[0])
        rows[sleep] = (wall, res)
        print(f"sleep={sleep!s:5}  wall {wall:6.2f} s (build {res.build_time_s:.2f} s, stepping "
              f"{res.wall_time_s:.2f} s)  steps {res.n_steps}  sim {res.sim_time_s:.2f} s  "
              f"all_at_rest {res.all_at_rest}  kept {len(res.names)}  removed "
              f"{[(r.name, r.reason) for r in res.removed]}  overlap start/end "
              f"{1e3 * res.initial_penetration_m:.1f}/{1e3 * res.final_penetration_m:.1f} mm  "
              f"touching pairs {len(res.touching)}")
        print(f"    settle times (s): median {np.median(res.settle_time_s):.2f}, max {res.settle_time_s.max():.2f}")
    (w1, r1), (w0, r0) = rows[True], rows[False]
    print(f"saving: {w0:.2f} s -> {w1:.2f} s ({100 * (1 - w1 / w0):.0f} % less wall time, {w0 / w1:.1f}x); "
          f"mean step {1e3 * r0.wall_time_s / max(r0.n_steps, 1):.2f} ms -> "
          f"{1e3 * r1.wall_time_s / max(r1.n_steps, 1):.2f} ms")
    common = [n for n in r1.names if n in r0.names]
    d = np.array([np.linalg.norm(r1.pose(n)[0] - r0.pose(n)[0]) for n in common])
    print(f"final positions, sleep vs no sleep: median difference {1e3 * np.median(d):.1f} mm, "
          f"{int((d > 0.05).sum())} of {len(d)} bodies differ by > 5 cm (contact-rich settling is chaotic)")


if __name__ == "__main__":
    main()
