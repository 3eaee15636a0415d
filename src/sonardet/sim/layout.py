"""Spawn layouts of reef elements in a scene, before physics settles them.

Each class has the arrangement it has on the real reef (Nienhagen; the `arrangement` of its spec in
sonardet.objects.classes), used for a share of a scene's objects; the rest are scattered at random:
- cluster (reef_cone): clusters on a hexagonal grid with gaps of cone_gap_m between bases;
- stack (reef_ring, two layers) and pile (tetrapod_s, up to three layers): rows, each layer over the
  gaps of the one below; a share ``scenes.dump_fraction`` of the piles is instead *dumped*: 15-20
  (``scenes.dump_n``) elements with random 3-D orientations poured one above the other into a ring
  fence (:class:`Fence`) that the physics removes once they rest, so the pile slumps
  (sonardet.sim.scene.settle_dumps). ``dump_fraction`` is the chance that a scene has one dumped pile
  of each piled class (:func:`draw_dumps`); the class's other arranged elements are laid in rows;
- spaced (tetrapod_b): single elements big_spacing_m apart;
- scatter: none (scattered only).

Positions are in the scene frame (m). A spawn is the pose of the canonical frame before dropping:
its z is set so that the body's lowest point clears the seabed (or the layer below) by spawn_gap_m.
Footprints never overlap at spawn (layers of a pile are stacked vertically instead; the bounding
spheres of a dumped pile's elements are disjoint), so physics starts without interpenetration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import quat_from_yaw, quat_to_matrix, random_quat
from ..objects import classes


@dataclass
class Fence:
    """The ring fence a dumped pile is poured into: centre (x, y) m, inner radius_m, height_m above
    the seabed at the centre; the physics keeps it only until the pile rests."""

    x: float
    y: float
    radius_m: float
    height_m: float


@dataclass
class Spawn:
    """One body to drop: class, canonical-frame pose (t (3,), q (4,) w,x,y,z), arrangement name,
    group index (-1 for scattered) and layer (0 = bottom); fence: the ring fence of a dumped pile's
    element (None otherwise)."""

    cls: str
    t: np.ndarray
    q: np.ndarray
    arrangement: str
    group: int
    layer: int
    fence: Fence | None = None


#: Share of a dumped pile's layer area its elements fill (sets the fence radius from the count).
DUMP_PACKING = 0.5
#: Free space kept around a fence (m): the fence wall and the slump when it is removed.
FENCE_CLEARANCE_M = 1.0


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


class _Planner:
    """The state of one layout: free space, spawns so far, group counter, and the scene's draws."""

    def __init__(self, radius_m, height_m, vertices, extent_xy, cfg, ground_z, rng):
        self.radius_m, self.height_m, self.vertices = radius_m, height_m, vertices
        self.extent, self.cfg, self.ground_z, self.rng = extent_xy, cfg, ground_z, rng
        self.occ = _Occupancy()
        self.spawns: list[Spawn] = []
        self.group = 0

    def random_centre(self, r, margin=0.0, tries=400):
        """A free disc centre of radius r (m) inside the scene, or None after `tries` draws."""
        xmin, xmax, ymin, ymax = self.extent
        for _ in range(tries):
            x = self.rng.uniform(xmin + r + margin, xmax - r - margin)
            y = self.rng.uniform(ymin + r + margin, ymax - r - margin)
            if self.occ.free(x, y, r):
                return x, y
        return None

    def spawn_at(self, cls, x, y, q, arrangement, grp, layer, base_z=None):
        """Spawn `cls` at (x, y) with orientation q, its lowest point spawn_gap_m above base_z (default:
        the seabed)."""
        low = _lowest_z(self.vertices[cls], q)
        z0 = self.ground_z(x, y) if base_z is None else base_z
        self.spawns.append(Spawn(cls, np.array([x, y, z0 - low + self.cfg["spawn_gap_m"]]), q, arrangement, grp,
                                 layer))

    def random_yaw(self):
        return quat_from_yaw(self.rng.uniform(-np.pi, np.pi))

    def clusters(self, cls: str, n_group: int) -> int:
        """Hexagonal clusters of up to cluster_max objects, gaps of cone_gap_m between bases; returns
        how many could not be placed."""
        r, cfg = self.radius_m[cls], self.cfg
        while n_group > 0:
            k = min(n_group, cfg["cluster_max"])
            pitch = 2 * r + self.rng.uniform(*cfg["cone_gap_m"])
            rows = int(np.ceil(np.sqrt(k))) + 2
            ii, jj = np.meshgrid(np.arange(-rows, rows + 1), np.arange(-rows, rows + 1))
            hx = (ii + 0.5 * (jj % 2)) * pitch
            hy = jj * pitch * np.sqrt(3) / 2
            order = np.argsort(np.hypot(hx, hy).ravel(), kind="stable")[:k]
            offs = np.c_[hx.ravel()[order], hy.ravel()[order]]
            extent_r = float(np.max(np.hypot(offs[:, 0], offs[:, 1]))) + r
            c = self.random_centre(extent_r)
            if c is None:
                break
            for ox, oy in offs:
                self.spawn_at(cls, c[0] + ox, c[1] + oy, self.random_yaw(), "cluster", self.group, 0)
            self.occ.add(c[0], c[1], extent_r)
            self.group += 1
            n_group -= k
        return n_group

    def rows(self, cls: str, n_group: int, arrangement: str) -> int:
        """Stacks or piles on a square grid (up to pile_max objects, scenes.pile_layers layers); each
        upper layer sits over the gaps of the one below. Returns how many could not be placed."""
        r, cfg = self.radius_m[cls], self.cfg
        layers = cfg["pile_layers"][cls]
        pitch = 2 * r + cfg["pile_gap_m"]
        while n_group > 0:
            k = min(n_group, cfg["pile_max"])
            # A row of b bottom elements; layer L holds b - L elements over the gaps of the row below
            # (a truncated pyramid in section). b is the smallest row that holds k.
            b = 1
            while sum(max(b - L, 0) for L in range(layers)) < k:
                b += 1
            extent_r = 0.5 * (b - 1) * pitch + r
            c = self.random_centre(extent_r)
            if c is None:
                break
            heading = self.rng.uniform(0, np.pi)
            ux, uy = np.cos(heading), np.sin(heading)
            placed, base = 0, 0.0
            for L in range(layers):
                for j in range(b - L):
                    if placed >= k:
                        break
                    off = (j - 0.5 * (b - L - 1)) * pitch
                    x, y = c[0] + off * ux, c[1] + off * uy
                    # Upright with a random yaw: no two bodies of a layer overlap at spawn; upper layers
                    # drop into the gaps below and tilt as the physics decides.
                    q = self.random_yaw()
                    ground = self.ground_z(x, y) + base if L > 0 else None
                    self.spawn_at(cls, x, y, q, arrangement, self.group, L, ground)
                    placed += 1
                base += self.height_m[cls] + cfg["spawn_gap_m"]
            self.occ.add(c[0], c[1], extent_r)
            self.group += 1
            n_group -= placed
        return n_group

    def dump(self, cls: str, k: int) -> int:
        """One pile of k elements poured into a ring fence: random 3-D orientations, random spots inside
        the fence, each spawned at the lowest height where its bounding sphere clears the seabed and
        every element poured before it (so they land one after another). The fence's radius holds
        the pile in scenes.pile_layers[cls] layers at a packing of DUMP_PACKING. Returns 0, or k when
        there is no room."""
        r, cfg = self.radius_m[cls], self.cfg
        layers = max(1, int(cfg["pile_layers"][cls]))
        fence_r = max(1.5 * r, r * float(np.sqrt(k / (layers * DUMP_PACKING))))
        c = self.random_centre(fence_r + FENCE_CLEARANCE_M)
        if c is None:
            return k
        ground = self.ground_z(c[0], c[1])
        fence = Fence(float(c[0]), float(c[1]), float(fence_r), float(layers * self.height_m[cls] + 0.5))
        v = self.vertices[cls]
        spheres: list[tuple[np.ndarray, float]] = []
        for i in range(k):
            q = random_quat(self.rng)
            vr = v @ quat_to_matrix(q).T
            mid = 0.5 * (vr.min(0) + vr.max(0))
            rb = float(np.linalg.norm(vr - mid, axis=1).max())
            rad = max(fence_r - rb, 0.0) * np.sqrt(self.rng.random())
            ang = self.rng.uniform(0, 2 * np.pi)
            xy = np.array([c[0] + rad * np.cos(ang), c[1] + rad * np.sin(ang)])
            zc = max(ground, self.ground_z(*xy)) + rb + cfg["spawn_gap_m"]
            for cen, rb2 in spheres:  # rise above every sphere this one would touch
                d_xy = float(np.hypot(*(cen[:2] - xy)))
                reach = rb + rb2 + cfg["spawn_gap_m"]
                if d_xy < reach:
                    zc = max(zc, cen[2] + np.sqrt(reach ** 2 - d_xy ** 2))
            cen = np.array([xy[0], xy[1], zc])
            spheres.append((cen, rb))
            self.spawns.append(Spawn(cls, cen - mid, q, "pile", self.group, min(layers - 1, i * layers // k),
                                     fence))
        self.occ.add(c[0], c[1], fence_r + FENCE_CLEARANCE_M)
        self.group += 1
        return 0

    def spaced(self, cls: str, n_group: int) -> int:
        """Single objects at least big_spacing_m[0] apart where room allows; returns how many could not
        be placed."""
        r = self.radius_m[cls]
        xmin, xmax, ymin, ymax = self.extent
        big, left = [], 0
        for _ in range(n_group):
            placed = False
            for _ in range(400):
                x = self.rng.uniform(xmin + r, xmax - r)
                y = self.rng.uniform(ymin + r, ymax - r)
                if big:
                    d = np.min(np.hypot(np.array(big)[:, 0] - x, np.array(big)[:, 1] - y))
                    if d < self.cfg["big_spacing_m"][0]:
                        continue
                if self.occ.free(x, y, r):
                    placed = True
                    break
            if not placed:
                left += 1
                continue
            big.append((x, y))
            self.occ.add(x, y, r)
            self.spawn_at(cls, x, y, self.random_yaw(), "single", self.group, 0)
            self.group += 1
        return left

    def scatter(self, cls: str, n: int, unplaced: list[str]) -> None:
        """Objects at random free spots, a share tumbled (random 3-D orientation)."""
        r = self.radius_m[cls]
        for _ in range(n):
            q = random_quat(self.rng) if self.rng.random() < self.cfg["tumbled_fraction"] else self.random_yaw()
            c = self.random_centre(r)
            if c is None:
                unplaced.append(f"{cls}: no free spot for a scattered object")
                continue
            self.occ.add(c[0], c[1], r)
            self.spawn_at(cls, c[0], c[1], q, "scatter", -1, 0)


def draw_dumps(counts: dict, cfg: dict, rng: np.random.Generator) -> dict:
    """Dumped piles of one scene: class -> elements in its dumped pile, for the classes whose arrangement
    is `pile`, each with probability scenes.dump_fraction (no draw at all when it is 0, so layouts
    without dumps are those of earlier versions). A pile holds dump_n elements (uniform in [min, max]);
    when the scene drew fewer of the class, the shortfall is taken from the other classes, the most
    numerous first (ties by name), at most half of their objects (a small scene, e.g. a hybrid one,
    keeps a mix), so the scene's total is kept and a dumped pile has the size real dumps have.
    `counts` (class -> objects) is updated in place; a class drawn with no element gets no pile (its
    weight in scenes.class_mix may be 0)."""
    frac = float(cfg["dump_fraction"])
    out: dict = {}
    if frac <= 0:
        return out
    lo, hi = cfg["dump_n"]
    for cls in sorted(counts):
        if classes.get(cls).arrangement != "pile" or counts[cls] <= 0 or rng.random() >= frac:
            continue
        k = int(rng.integers(lo, hi + 1))
        donors = [c for c in sorted(counts) if c != cls and c not in out]
        budget = sum(counts[c] for c in donors) // 2
        for _ in range(min(max(k - counts[cls], 0), budget)):
            donor = max(donors, key=lambda c: counts[c])  # first of the most numerous (names sorted)
            counts[donor] -= 1
            counts[cls] += 1
        out[cls] = min(k, counts[cls])
    return out


def plan_layout(counts: dict, radius_m: dict, height_m: dict, vertices: dict, extent_xy, cfg: dict,
                ground_z, rng: np.random.Generator) -> tuple[list[Spawn], list[str]]:
    """Plan spawns for `counts` objects per class inside extent_xy = (xmin, xmax, ymin, ymax).

    radius_m / height_m: horizontal radius and height of each class (m); vertices: (V,3) canonical
    vertices of each class (to place a rotated body just above the ground); cfg: the `scenes`
    section; ground_z(x, y) -> seabed elevation (m). Each class's arrangement comes from its spec
    (sonardet.objects.classes); dumped piles (`draw_dumps`) may move a few objects between classes,
    the total kept. Returns the spawns and a list of messages about objects that could
    not be placed (never dropped silently: the caller logs and records them).
    """
    plan = _Planner(radius_m, height_m, vertices, extent_xy, cfg, ground_z, rng)
    unplaced: list[str] = []
    scatter_share = rng.uniform(*cfg["scatter_fraction"])
    counts = {c: int(k) for c, k in counts.items()}
    dumps = draw_dumps(counts, cfg, rng)
    for cls in sorted(counts):
        n = counts[cls] - dumps.get(cls, 0)
        n_scatter = int(round(n * scatter_share))
        n_group = n - n_scatter
        arrangement = classes.get(cls).arrangement
        if dumps.get(cls):
            n_scatter += plan.dump(cls, dumps[cls])
        if n_group > 0 and arrangement == "cluster":
            n_scatter += plan.clusters(cls, n_group)
        elif n_group > 0 and arrangement == "pile":
            n_scatter += plan.rows(cls, n_group, "pile")
        elif n_group > 0 and arrangement == "stack":
            n_scatter += plan.rows(cls, n_group, arrangement)
        elif n_group > 0 and arrangement == "spaced":
            n_scatter += plan.spaced(cls, n_group)
        else:
            n_scatter += n_group
        plan.scatter(cls, n_scatter, unplaced)
    return plan.spawns, unplaced
