"""Spawn layouts of reef elements in a scene, before physics settles them.

Each class has the arrangement it has on the real reef (Nienhagen), used for a share of a scene's
objects; the rest are scattered at random:
- reef_cone: clusters on a hexagonal grid with gaps of cone_gap_m between bases;
- reef_ring: stacks of two layers, upper rings straddling two lower ones;
- tetrapod_s: piles of up to three layers (rows: each layer over the gaps of the one below);
- tetrapod_b: single elements big_spacing_m apart.

Positions are in the scene frame (m). A spawn is the pose of the canonical frame before dropping:
its z is set so that the body's lowest point clears the seabed (or the layer below) by spawn_gap_m.
Footprints never overlap at spawn (layers of a pile are stacked vertically instead), so physics
starts without interpenetration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import quat_from_yaw, quat_to_matrix, random_quat


@dataclass
class Spawn:
    """One body to drop: class, canonical-frame pose (t (3,), q (4,) w,x,y,z), arrangement name,
    group index (-1 for scattered) and layer (0 = bottom)."""

    cls: str
    t: np.ndarray
    q: np.ndarray
    arrangement: str
    group: int
    layer: int


class _Occupancy:
    """Discs (x, y, r) already taken in the xy plane."""

    def __init__(self):
        self.discs = np.zeros((0, 3))

    def free(self, x, y, r, gap=0.05) -> bool:
        if len(self.discs) == 0:
            return True
        d = np.hypot(self.discs[:, 0] - x, self.discs[:, 1] - y)
        return bool(np.all(d >= self.discs[:, 2] + r + gap))

    def add(self, x, y, r):
        self.discs = np.vstack([self.discs, [x, y, r]])


def _lowest_z(parts_vertices: np.ndarray, q) -> float:
    return float((parts_vertices @ quat_to_matrix(q).T)[:, 2].min())


def plan_layout(counts: dict, radius_m: dict, height_m: dict, vertices: dict, extent_xy, cfg: dict,
                ground_z, rng: np.random.Generator) -> tuple[list[Spawn], list[str]]:
    """Plan spawns for `counts` objects per class inside extent_xy = (xmin, xmax, ymin, ymax).

    radius_m / height_m: horizontal radius and height of each class (m); vertices: (V,3) canonical
    vertices of each class (to place a rotated body just above the ground); cfg: the `scenes`
    section; ground_z(x, y) -> seabed elevation (m). Returns the spawns and a list of messages about
    objects that could not be placed (never dropped silently: the caller logs and records them).
    """
    xmin, xmax, ymin, ymax = extent_xy
    occ = _Occupancy()
    spawns: list[Spawn] = []
    unplaced: list[str] = []
    gap = cfg["spawn_gap_m"]
    scatter_share = rng.uniform(*cfg["scatter_fraction"])
    group = 0

    def random_centre(r, margin=0.0, tries=400):
        for _ in range(tries):
            x = rng.uniform(xmin + r + margin, xmax - r - margin)
            y = rng.uniform(ymin + r + margin, ymax - r - margin)
            if occ.free(x, y, r):
                return x, y
        return None

    def spawn_at(cls, x, y, q, arrangement, grp, layer, base_z=None):
        low = _lowest_z(vertices[cls], q)
        z0 = ground_z(x, y) if base_z is None else base_z
        spawns.append(Spawn(cls, np.array([x, y, z0 - low + gap]), q, arrangement, grp, layer))

    for cls in sorted(counts):
        n = int(counts[cls])
        n_scatter = int(round(n * scatter_share))
        n_group = n - n_scatter
        r = radius_m[cls]
        if n_group > 0 and cls == "reef_cone":
            # One cluster per up to cluster_max cones: hexagonal grid, gaps <= cone_gap_m.
            while n_group > 0:
                k = min(n_group, cfg["cluster_max"])
                pitch = 2 * r + rng.uniform(*cfg["cone_gap_m"])
                rows = int(np.ceil(np.sqrt(k))) + 2
                ii, jj = np.meshgrid(np.arange(-rows, rows + 1), np.arange(-rows, rows + 1))
                hx = (ii + 0.5 * (jj % 2)) * pitch
                hy = jj * pitch * np.sqrt(3) / 2
                order = np.argsort(np.hypot(hx, hy).ravel(), kind="stable")[:k]
                offs = np.c_[hx.ravel()[order], hy.ravel()[order]]
                extent_r = float(np.max(np.hypot(offs[:, 0], offs[:, 1]))) + r
                c = random_centre(extent_r)
                if c is None:
                    break
                for ox, oy in offs:
                    spawn_at(cls, c[0] + ox, c[1] + oy, quat_from_yaw(rng.uniform(-np.pi, np.pi)), "cluster",
                             group, 0)
                occ.add(c[0], c[1], extent_r)
                group += 1
                n_group -= k
            n_scatter += n_group
        elif n_group > 0 and cls in ("reef_ring", "tetrapod_s"):
            # Stacks (rings, 2 layers) and piles (small tetrapods, up to 3 layers) on a square grid;
            # each upper layer sits over the gaps of the one below.
            layers = cfg["pile_layers"][cls]
            pitch = 2 * r + cfg["pile_gap_m"]
            while n_group > 0:
                k = min(n_group, cfg["pile_max"])
                # A row of b bottom elements; layer L holds b - L elements over the gaps of the row
                # below (a truncated pyramid in section). b is the smallest row that holds k.
                b = 1
                while sum(max(b - L, 0) for L in range(layers)) < k:
                    b += 1
                extent_r = 0.5 * (b - 1) * pitch + r
                c = random_centre(extent_r)
                if c is None:
                    break
                heading = rng.uniform(0, np.pi)
                ux, uy = np.cos(heading), np.sin(heading)
                placed, base = 0, 0.0
                for L in range(layers):
                    for j in range(b - L):
                        if placed >= k:
                            break
                        off = (j - 0.5 * (b - L - 1)) * pitch
                        x, y = c[0] + off * ux, c[1] + off * uy
                        # Upright with a random yaw: no two bodies of a layer overlap at spawn; upper
                        # layers drop into the gaps below and tilt as the physics decides.
                        q = quat_from_yaw(rng.uniform(-np.pi, np.pi))
                        ground = ground_z(x, y) + base if L > 0 else None
                        spawn_at(cls, x, y, q, "stack" if cls == "reef_ring" else "pile", group, L, ground)
                        placed += 1
                    base += height_m[cls] + gap
                occ.add(c[0], c[1], extent_r)
                group += 1
                n_group -= placed
            n_scatter += n_group
        elif n_group > 0 and cls == "tetrapod_b":
            big = []
            for _ in range(n_group):
                placed = False
                for _ in range(400):
                    x = rng.uniform(xmin + r, xmax - r)
                    y = rng.uniform(ymin + r, ymax - r)
                    if big:
                        d = np.min(np.hypot(np.array(big)[:, 0] - x, np.array(big)[:, 1] - y))
                        if d < cfg["big_spacing_m"][0]:
                            continue
                    if occ.free(x, y, r):
                        placed = True
                        break
                if not placed:
                    n_scatter += 1
                    continue
                big.append((x, y))
                occ.add(x, y, r)
                spawn_at(cls, x, y, quat_from_yaw(rng.uniform(-np.pi, np.pi)), "single", group, 0)
                group += 1
        else:
            n_scatter += n_group
        for _ in range(n_scatter):
            q = random_quat(rng) if rng.random() < cfg["tumbled_fraction"] else quat_from_yaw(rng.uniform(-np.pi, np.pi))
            c = random_centre(r)
            if c is None:
                unplaced.append(f"{cls}: no free spot for a scattered object")
                continue
            occ.add(c[0], c[1], r)
            spawn_at(cls, c[0], c[1], q, "scatter", -1, 0)
    return spawns, unplaced
