"""Scores of a posed class model against the scene: two-way inlier fractions, robust RMSE, plausibility.

All positions in the detector's local scene frame (metres); a pose (R, t) maps canonical object
coordinates into it. Definitions (per hypothesis):

* candidate points: object-candidate scene points (above the seabed) inside the posed evaluation box
  grown by `candidate_box_margin_m`;
* inliers: candidates closer than `inlier_m` to the posed mesh, after the shape tolerance: real
  objects are not their models (legs a third thinner or thicker, a fouling shell), so the signed
  distances (outside +, inside -) may first be shifted by their median, bounded by
  `shape_tolerance_frac` x the class's half thickness (0: off), i.e. the model is allowed to be
  uniformly too thick or too thin by that much;
* g_h (gross height): the class must agree with how tall the soundings show the object to be.
  Unexplained candidate points above the posed box (within the central `overhang_core_frac` of its
  footprint, where a taller object of the same kind rises and a pile neighbour rarely does, up to
  `overhang_max_frac` x the box height above its top plus `candidate_box_margin_m`) are evidence of a
  taller object: with dz the height above that top of the
  `overhang_min_points_n`-th highest of them, g_h = 1 - dz / (`overhang_max_frac` x box height),
  clipped to [0, 1] (1 when fewer points or when off, frac 0). A small class fitted to the lower part
  of a big object loses, while an object under another one (a pile, a ring stack) is not penalised:
  points explained by an accepted object, or inliers of a pending hypothesis whose centre lies above
  this box's top (`support_overhangs`), do not count;
* f_s (scene -> model): inliers / candidates, both counted only over points not yet explained by an
  accepted object, so a clutter blob or a neighbour inside the box lowers it, while an object already
  accepted (the ring on top of this one) does not; nor do the inliers of a compatible pending
  neighbour (`support_neighbours`: members of a pile whose legs reach into each other's boxes);
* f_t (model -> scene): share of the template points that have a scene point within `coverage_m`, best
  over the class's template views (each view is a real scan with the sensor's occlusion pattern, so
  template parts the sonar cannot see are not asked for); tumbled poses, which the upright template
  scans do not cover, use virtual views instead (the posed mesh ray-cast from nadir and oblique
  directions, `virtual_view_incidences_deg`, `virtual_views`); template points hidden under accepted
  objects are not asked for (`hidden_under`);
* rmse: RMS point-to-mesh distance of the inliers (m);
* score = f_t * f_s * (1 - (rmse / rmse_max)^2), in [0, 1], higher is better.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from ...geometry import matrix_to_quat, points_in_box
from ...jit import numba
from ...objects.catalog import canonical_box
from .near import NearGrid, xy_cells


@dataclass(eq=False)
class Hypothesis:
    """A posed class model with its scores. `cand` indexes the object-candidate point array; `inl`
    (bool, len(cand)) marks the inliers among them."""

    cls: str
    R: np.ndarray
    t: np.ndarray
    box: np.ndarray
    f_t: float = 0.0
    f_s: float = 0.0
    rmse_m: float = 1.0
    fitness: float = 0.0
    score: float = 0.0
    #: How much thicker (+) or thinner (-) than its model the object appears (m; 0 without a shape tolerance).
    shape_offset_m: float = 0.0
    #: Gross height consistency in [0, 1] (module doc); over/over_dz: the candidate points above the box
    #: and their heights (m) above its top (plus margin), so it follows what gets explained.
    g_h: float = 1.0
    over: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    over_dz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    over_range_m: float = 0.0
    #: Which overhang points may count (False: an inlier of a hypothesis above this one).
    over_free: np.ndarray | None = None
    #: Which candidate points count against f_s (False: an inlier of a compatible neighbour hypothesis,
    #: see `support_neighbours`); None: all.
    cand_free: np.ndarray | None = None
    cand: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    inl: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    upright: bool = True
    round: int = 0
    seed_xy: np.ndarray | None = None
    n_refits: int = 0
    uid: int = -1

    @property
    def q(self) -> np.ndarray:
        """The rotation R as a unit quaternion (w, x, y, z)."""
        return matrix_to_quat(self.R)


def up_tilt_rad(model, R: np.ndarray) -> float:
    """Tilt (rad) of the object from a resting pose: the smallest angle between one of its class's
    up axes (`model.up_axes`; z for most classes, each leg for a tetrapod, which rests on any three)
    posed by R and the scene's z axis."""
    up = (R @ model.up_axes.T)[2]
    return float(np.arccos(np.clip(up.max(), -1.0, 1.0)))


def view_points(views: list, voxel_m: float) -> list:
    """Template views (canonical frame, m) thinned to one point (the first) per `voxel_m` voxel; empty
    views are left out."""
    out = []
    for v in views:
        if len(v) == 0:
            continue
        k = np.floor(v / voxel_m).astype(np.int64)
        _, first = np.unique(k, axis=0, return_index=True)
        out.append(v[np.sort(first)])
    return out


@dataclass
class CoverageViews:
    """A class's thinned template views prepared for coverage scoring (canonical frame, m): all points
    (K,3) of the views one after another, the outward normal (K,3) of the model surface sample nearest
    to each (fixed, since the views are: the shape offset of a hypothesis moves them along these
    without a tree query per hypothesis), and the view boundaries (V+1,) in that array."""

    points: np.ndarray
    normals: np.ndarray
    bounds: np.ndarray

    @classmethod
    def of(cls, model, views: list) -> CoverageViews:
        """From `view_points` output and the class model (its surface samples and normals)."""
        pts = np.concatenate(views) if views else np.zeros((0, 3))
        if len(pts):
            _, i = model.surface_tree.query(pts, k=1)
            normals = model.surface_normals[i]
        else:
            normals = np.zeros((0, 3))
        return cls(pts, normals, np.cumsum([0] + [len(v) for v in views]))


def view_directions(incidences_deg, n_azimuth: int) -> np.ndarray:
    """Unit viewing directions (K,3), pointing down: one per incidence angle off nadir (deg; 0 = nadir,
    one direction) from `n_azimuth` evenly spread sides."""
    out = []
    for inc in np.deg2rad(incidences_deg):
        azs = [0.0] if inc == 0 else np.arange(n_azimuth) * 2 * np.pi / n_azimuth
        for az in azs:
            out.append([np.sin(inc) * np.cos(az), np.sin(inc) * np.sin(az), -np.cos(inc)])
    return np.asarray(out)


@functools.lru_cache(maxsize=16)
def _view_bases(directions_bytes: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (K,3) u and w spanning the ray-grid plane of each viewing direction d (K,3, given as
    the bytes of a float64 array): u = d x (y, or x for a near-y d), normalised, w = d x u. Cached:
    the directions are the same for every hypothesis."""
    dirs = np.frombuffer(directions_bytes, dtype=np.float64).reshape(-1, 3)
    us, ws = [], []
    for d in dirs:
        u = np.cross(d, [0.0, 1.0, 0.0] if abs(d[1]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        us.append(u)
        ws.append(np.cross(d, u))
    us, ws = np.array(us).reshape(-1, 3), np.array(ws).reshape(-1, 3)
    us.flags.writeable = ws.flags.writeable = False
    return us, ws


def virtual_views(model, R: np.ndarray, t: np.ndarray, cell_m: float, directions: np.ndarray) -> list:
    """Point sets (scene frame, m) of the posed mesh as seen along each of `directions` (K,3).

    For a pose the template scans do not cover (a tumbled object), each view casts a grid of parallel
    rays (spacing `cell_m`, m) from that direction at the posed mesh (Open3D ray casting on the
    canonical mesh, rays turned into its frame) and keeps the first hits: the surface a sonar looking
    from there could see, self-occlusion included. The scorer uses nadir and oblique looks from several
    sides (`view_directions`), like the template views' across-track offsets.
    """
    v = model.vertices @ R.T + t
    c = 0.5 * (v.min(0) + v.max(0))
    r = 0.5 * float(np.linalg.norm(v.max(0) - v.min(0))) + cell_m
    g = np.arange(-r, r + 1e-9, cell_m)
    gu, gv = (x.reshape(-1) for x in np.meshgrid(g, g))
    us, ws = _view_bases(np.ascontiguousarray(directions, dtype=np.float64).tobytes())
    # Only rays that pass through the mesh's shadow on a view's (u, w) plane (its vertices' extent
    # there, a millimetre wider) can hit it: the others are left out, the rays kept are those of the
    # full grid, in its order, so the hits are the same.
    pu, pw = (v - c) @ us.T, (v - c) @ ws.T
    lo_u, hi_u = pu.min(0) - 1e-3, pu.max(0) + 1e-3
    lo_w, hi_w = pw.min(0) - 1e-3, pw.max(0) + 1e-3
    origins = []
    for k, d in enumerate(directions):
        keep = (gu >= lo_u[k]) & (gu <= hi_u[k]) & (gv >= lo_w[k]) & (gv <= hi_w[k])
        origins.append(c - 2.0 * r * d + gu[keep, None] * us[k] + gv[keep, None] * ws[k])
    counts = [len(o) for o in origins]
    # One cast for every view (the rays are independent): the per-call cost of the ray caster is paid once.
    dirs = np.repeat(np.asarray(directions, dtype=np.float64), counts, axis=0)
    o_all = np.concatenate(origins) if origins else np.zeros((0, 3))
    dist = model.cast((o_all - t) @ R, dirs @ R)
    out = []
    start = 0
    for k, o in enumerate(origins):
        dk = dist[start:start + counts[k]]
        start += counts[k]
        hit = np.isfinite(dk)
        out.append(o[hit] + dk[hit, None] * directions[k])
    return out


def hidden_under(points: np.ndarray, boxes, footprint_margin_m: float, above_bottom_m: float) -> np.ndarray:
    """Boolean (K,) of points (K,3, m) lying under one of the boxes [x,y,z,l,w,h,yaw] (m, rad): inside its
    footprint grown by `footprint_margin_m` and no higher than `above_bottom_m` above its bottom, i.e.
    hidden from above by that object."""
    out = np.zeros(len(points), dtype=bool)
    for b in boxes:
        dx, dy = points[:, 0] - b[0], points[:, 1] - b[1]
        c, s = np.cos(b[6]), np.sin(b[6])
        u, v = dx * c + dy * s, -dx * s + dy * c
        out |= (np.abs(u) <= 0.5 * b[3] + footprint_margin_m) & (np.abs(v) <= 0.5 * b[4] + footprint_margin_m) & \
               (points[:, 2] <= b[2] - 0.5 * b[5] + above_bottom_m)
    return out


@dataclass
class SceneIndex:
    """The scene points a hypothesis is scored against (detector's local frame, m).

    pts (N,3): object-candidate points (above the seabed); active (N,) bool: not yet explained by an
    accepted object; tree_xy: cKDTree over pts[:, :2]; all_xyz (M,3): every scene point, seabed
    included (the coverage term); all_tree_xy: cKDTree over all_xyz[:, :2].
    """

    pts: np.ndarray
    active: np.ndarray
    tree_xy: cKDTree
    all_xyz: np.ndarray
    all_tree_xy: cKDTree


def _asked(points: np.ndarray, occluders, params: dict) -> np.ndarray:
    """Boolean (K,): template points (scene frame) the sonar could see, i.e. not hidden under an occluder.
    (The scorer runs this test inside `_view_shares_max`; this NumPy form is its reference in the tests.)"""
    if not len(occluders):
        return np.ones(len(points), dtype=bool)
    return ~hidden_under(points, occluders, params["hidden_footprint_margin_m"], params["hidden_above_bottom_m"])


@numba.njit(cache=True, nogil=True)
def _shadow_tops(pts, cell):
    """Highest z of points (N,3, N > 0) per `cell` cell from (lo_x, lo_y) = their smallest x and y less
    one cell (shape: the largest cell index + 2 per axis, -inf where empty), then the highest of each
    cell's 3 x 3 neighbourhood: one compiled pass each (the same values as np.maximum.at and a 3 x 3
    maximum filter, without holding the GIL). Returns (raster, lo_x, lo_y)."""
    n = pts.shape[0]
    ii, jj, lo_x, lo_y = xy_cells(pts, cell, 1.0)
    n0 = ii.max() + 2
    n1 = jj.max() + 2
    top = np.full((n0, n1), -np.inf)
    for k in range(n):
        if pts[k, 2] > top[ii[k], jj[k]]:
            top[ii[k], jj[k]] = pts[k, 2]
    out = np.full((n0, n1), -np.inf)
    for i in range(n0):
        for j in range(n1):
            m = -np.inf
            for a in range(max(i - 1, 0), min(i + 2, n0)):
                for b in range(max(j - 1, 0), min(j + 2, n1)):
                    if top[a, b] > m:
                        m = top[a, b]
            out[i, j] = m
    return out, lo_x, lo_y


class ShadowMap:
    """Highest scene point (m) per `cell_m` xy cell around a hypothesis, for telling which of its template
    points the sonar could not see because something observed lies above them (a neighbour in a pile,
    a leg of another element): a template point is shadowed when a scene point in its cell or the 8
    around it lies more than `margin_m` above it. A vertical line of sight is assumed (near-nadir beams;
    an oblique beam that does reach the point gives it a scene point, and hit points are never excused)."""

    def __init__(self, pts: np.ndarray, cell_m: float, margin_m: float):
        self.cell, self.margin = float(cell_m), float(margin_m)
        if len(pts) == 0:
            raise ValueError("ShadowMap needs at least one scene point")
        self.top, lo_x, lo_y = _shadow_tops(np.ascontiguousarray(pts, dtype=np.float64), self.cell)
        self.lo = np.array([lo_x, lo_y])

    def shadowed(self, pts: np.ndarray) -> np.ndarray:
        """Boolean (K,): points (K,3, m) lying more than margin_m below the highest scene point near them."""
        ij = np.floor((pts[:, :2] - self.lo) / self.cell).astype(np.int64)
        ok = np.all((ij >= 0) & (ij < np.array(self.top.shape)), axis=1)
        out = np.zeros(len(pts), dtype=bool)
        out[ok] = pts[ok, 2] < self.top[ij[ok, 0], ij[ok, 1]] - self.margin
        return out


def _excused(points: np.ndarray, hit: np.ndarray, shadow) -> np.ndarray:
    """Boolean (K,): template points not hit and shadowed by observed points above them (none without a
    shadow map). (The scorer runs this test inside `_view_shares_max`; this form is its reference.)"""
    out = np.zeros(len(points), dtype=bool)
    miss = ~hit
    if shadow is not None and miss.any():
        out[miss] = shadow.shadowed(points[miss])
    return out


def _offset_along_normals(model, pts_canonical: np.ndarray, offset_m: float) -> np.ndarray:
    """Canonical points moved by offset_m (m) along the outward normal of the nearest model surface
    sample: where the surface of an object thicker (+) or thinner (-) than its model lies."""
    if offset_m == 0.0 or len(pts_canonical) == 0:
        return pts_canonical
    _, i = model.surface_tree.query(pts_canonical, k=1)
    return pts_canonical + offset_m * model.surface_normals[i]


@numba.njit(cache=True, nogil=True)
def _view_shares_max(pts, hit, bounds, boxes, cos_yaw, sin_yaw, footprint_margin, above_bottom, top, lo_x, lo_y,
                     cell, shadow_margin, floor_frac):
    """The best share over views (points pts[bounds[v]:bounds[v+1]]) of asked points that are hit; a
    point is asked unless it lies under an occluder box (`hidden_under`, the boxes' yaw cosines and
    sines given) or, not hit, in the shadow of `top` (`ShadowMap.shadowed`; `top` of shape (0, 0): no
    shadow map). The share's denominator is at least floor_frac x the view's size and 1. One compiled
    pass of `_asked`, `_excused` and the per-view counts, the same operations in the same order."""
    n0, n1 = top.shape
    best = 0.0
    for v in range(bounds.shape[0] - 1):
        n_hit = 0
        n_asked = 0
        for k in range(bounds[v], bounds[v + 1]):
            x, y, z = pts[k, 0], pts[k, 1], pts[k, 2]
            hidden = False
            for m in range(boxes.shape[0]):
                dx = x - boxes[m, 0]
                dy = y - boxes[m, 1]
                u = dx * cos_yaw[m] + dy * sin_yaw[m]
                w = -dx * sin_yaw[m] + dy * cos_yaw[m]
                if (abs(u) <= 0.5 * boxes[m, 3] + footprint_margin and abs(w) <= 0.5 * boxes[m, 4] + footprint_margin
                        and z <= boxes[m, 2] - 0.5 * boxes[m, 5] + above_bottom):
                    hidden = True
                    break
            if hidden:
                continue
            if not hit[k] and n0 > 0:
                i = int(np.floor((x - lo_x) / cell))
                j = int(np.floor((y - lo_y) / cell))
                if 0 <= i < n0 and 0 <= j < n1 and z < top[i, j] - shadow_margin:
                    continue  # excused: in the shadow of something observed above it
            n_asked += 1
            if hit[k]:
                n_hit += 1
        den = max(max(float(n_asked), floor_frac * (bounds[v + 1] - bounds[v])), 1.0)
        share = n_hit / den
        if v == 0 or share > best:
            best = share
    return best


def _best_view_share(pts: np.ndarray, hit: np.ndarray, bounds: np.ndarray, occluders, params: dict,
                     shadow: ShadowMap | None) -> float:
    """f_t from the posed views' points (K,3, scene frame, m; view v is pts[bounds[v]:bounds[v+1]]) and
    which of them have a scene point within coverage_m (`hit`): the best share over the views of asked
    points that are hit (`_asked`, `_excused`; 0 without views)."""
    if len(bounds) < 2:
        return 0.0
    boxes = np.asarray(occluders, dtype=np.float64).reshape(-1, 7)
    # The yaws' cosines and sines as `hidden_under` takes them (NumPy's), so the tests are the same bits.
    cos_yaw = np.array([np.cos(b[6]) for b in boxes])
    sin_yaw = np.array([np.sin(b[6]) for b in boxes])
    if shadow is None:
        top, lo, cell, margin = np.zeros((0, 0)), (0.0, 0.0), 1.0, 0.0
    else:
        top, lo, cell, margin = shadow.top, shadow.lo, shadow.cell, shadow.margin
    return float(_view_shares_max(np.ascontiguousarray(pts, dtype=np.float64), np.ascontiguousarray(hit), bounds,
                                  boxes, cos_yaw, sin_yaw, float(params["hidden_footprint_margin_m"]),
                                  float(params["hidden_above_bottom_m"]), top, float(lo[0]), float(lo[1]),
                                  float(cell), float(margin), float(params["coverage_asked_min_frac"])))


def _coverage_upright(views: CoverageViews, R, t, near: NearGrid, occluders, params: dict,
                      offset_m: float = 0.0, shadow: ShadowMap | None = None) -> float:
    """f_t of an upright pose: best over the thinned template views (canonical, moved by the shape offset
    `offset_m` along their normals, posed by R, t) of the share of asked points with a scene point
    within coverage_m (points under accepted occluders or, unhit, in the shadow map's shadow are not
    asked)."""
    pts = views.points + offset_m * views.normals if offset_m else views.points
    allv = pts @ R.T + t
    return _best_view_share(allv, near.any_within(allv), np.asarray(views.bounds, dtype=np.int64), occluders,
                            params, shadow)


def _coverage_virtual(model, R, t, near: NearGrid, occluders, params: dict, offset_m: float = 0.0,
                      shadow: ShadowMap | None = None) -> float:
    """f_t of a tumbled pose: best over the virtual views of the posed mesh (see `virtual_views`) with at
    least virtual_view_min_points_n points, moved by the shape offset `offset_m` along their normals.
    The views' points are tested together and counted per view in one compiled pass
    (`_best_view_share`; the same shares as one test per view)."""
    dirs = view_directions(params["virtual_view_incidences_deg"], int(params["virtual_view_azimuths_n"]))
    views = [pv for pv in virtual_views(model, R, t, params["coverage_voxel_m"], dirs)
             if len(pv) >= params["virtual_view_min_points_n"]]
    if not views:
        return 0.0
    pts = np.concatenate(views)
    if offset_m:
        pts = _offset_along_normals(model, (pts - t) @ R, offset_m) @ R.T + t
    bounds = np.cumsum([0] + [len(v) for v in views]).astype(np.int64)
    return _best_view_share(pts, near.any_within(pts), bounds, occluders, params, shadow)


def _overhang(h: Hypothesis, scene: SceneIndex, near: np.ndarray, params: dict) -> None:
    """Fill h.over, h.over_dz, h.over_range_m: the candidate points (of `near`) above h's box, within the
    central overhang_core_frac of its footprint, up to overhang_max_frac x its height above its top plus
    candidate_box_margin_m (see the module doc); nothing when overhang_max_frac is 0."""
    frac = float(params["overhang_max_frac"])
    if frac <= 0:
        return
    box, margin = h.box, float(params["candidate_box_margin_m"])
    top = box[2] + 0.5 * box[5] + margin
    h.over_range_m = frac * float(box[5])
    core = float(params["overhang_core_frac"])
    slab = np.array([box[0], box[1], top + 0.5 * h.over_range_m, core * box[3], core * box[4], h.over_range_m,
                     box[6]])
    h.over = near[points_in_box(scene.pts[near], slab)]
    h.over_dz = scene.pts[h.over, 2] - top


def height_consistency(h: Hypothesis, active: np.ndarray, params: dict) -> float:
    """g_h of the module doc from h's overhang points still unexplained (`active`)."""
    if h.over_range_m <= 0 or len(h.over) == 0:
        return 1.0
    free = active[h.over] if h.over_free is None else active[h.over] & h.over_free
    dz = h.over_dz[free]
    n = int(params["overhang_min_points_n"])
    if len(dz) < n:
        return 1.0
    top_n = float(np.partition(dz, len(dz) - n)[len(dz) - n])
    return float(np.clip(1.0 - top_n / h.over_range_m, 0.0, 1.0))


def support_overhangs(hyps: list, n_points: int) -> None:
    """Set `over_free` of every hypothesis in `hyps`: its overhang points that are inliers of another
    hypothesis of `hyps` whose box centre lies above its box top do not count (the object above it in a
    pile or a stack explains them). A taller object seen as a small class keeps its overhang, since no
    hypothesis of that object has its centre above the small box's top. n_points: size of the candidate
    point array the hypotheses index."""
    support_z = np.full(n_points, -np.inf)
    for h in hyps:
        inl = h.cand[h.inl]
        np.maximum.at(support_z, inl, float(h.box[2]))
    for h in hyps:
        if len(h.over):
            top = float(h.box[2] + 0.5 * h.box[5])
            h.over_free = support_z[h.over] <= top


def support_neighbours(targets: list, supporters: list, n_points: int, rmse_max: dict, params: dict) -> None:
    """Set `cand_free` of every hypothesis in `targets`: its candidate points that are not its own
    inliers but are inliers of a compatible supporter do not count against its f_s.

    In a dumped pile the legs of touching members reach into each other's boxes; while neither is
    accepted, each one's points lower the other's f_s and both can stay below `accept_min`. A supporter
    is a hypothesis of `supporters` with f_t >= `neighbour_support_f_t_min` and its RMSE within its
    class limit `rmse_max` (m, per class); it is compatible with a target when they share at most
    `neighbour_support_overlap_max_frac` of the smaller inlier set (two fits of one object, or a small
    class on part of a big object, share most of theirs and do not excuse each other). Off when that
    fraction is 0. n_points: size of the candidate point array the hypotheses index.

    Written here because it is specific to this explain-away; it is one sparse product over the
    hypotheses' inlier sets (scipy.sparse)."""
    frac = float(params["neighbour_support_overlap_max_frac"])
    if frac <= 0 or not targets:
        return
    f_t_min = float(params["neighbour_support_f_t_min"])
    sup = [s for s in supporters if s.inl.any() and s.f_t >= f_t_min and s.rmse_m <= rmse_max[s.cls]]
    if not sup:
        return

    def inlier_matrix(hs):
        rows = np.concatenate([np.full(int(h.inl.sum()), i) for i, h in enumerate(hs)])
        cols = np.concatenate([h.cand[h.inl] for h in hs])
        return sparse.csr_matrix((np.ones(len(rows), np.float32), (rows, cols)), shape=(len(hs), n_points))

    it, isup = inlier_matrix(targets), inlier_matrix(sup)
    shared = (it @ isup.T).toarray()  # inliers each target shares with each supporter
    n_t = np.asarray(it.sum(1)).ravel()
    n_s = np.asarray(isup.sum(1)).ravel()
    ok = shared <= frac * np.minimum(n_t[:, None], n_s[None, :])
    col_of = {id(s): j for j, s in enumerate(sup)}
    for i, t in enumerate(targets):  # a hypothesis does not support itself
        if id(t) in col_of:
            ok[i, col_of[id(t)]] = False
    covered = (sparse.csr_matrix(ok.astype(np.float32)) @ isup).tocsr()  # (targets, points) > 0: excused
    for i, h in enumerate(targets):
        if len(h.cand):
            row = slice(covered.indptr[i], covered.indptr[i + 1])
            h.cand_free = h.inl | ~np.isin(h.cand, covered.indices[row][covered.data[row] > 0])


def shape_tolerance_m(model, params: dict) -> float:
    """How much thicker or thinner (m) than its model an object of the model's class may be:
    `shape_tolerance_frac` x the class's median half thickness (0 when off)."""
    return max(0.0, float(params["shape_tolerance_frac"]) * float(model.half_thickness_m))


def _shape_residual(model, pts_canonical: np.ndarray, params: dict) -> tuple[np.ndarray, float]:
    """Distances (m, (K,)) of canonical points to the model surface, allowing the object to be uniformly
    thicker or thinner than the model, and that offset (m, + thicker): with a shape tolerance tau
    (`shape_tolerance_m`), the signed distances near the surface (within tau + inlier_m) are shifted by
    their median, clipped to [-tau, tau]; without one, the plain distances and 0."""
    tau = shape_tolerance_m(model, params)
    if tau <= 0:
        return model.distance(pts_canonical), 0.0
    # Only distances below tau + inlier_m matter (the points near the surface, and the inliers after
    # the shift by at most tau): farther ones come back as +inf, which both tests reject.
    sd = model.signed_distance(pts_canonical, bound_m=tau + params["inlier_m"])
    near = np.abs(sd) < tau + params["inlier_m"]
    offset = float(np.clip(np.median(sd[near]), -tau, tau)) if near.any() else 0.0
    return np.abs(sd - offset), offset


def tolerant_distance(model, pts_canonical: np.ndarray, params: dict) -> np.ndarray:
    """Distance (m) of canonical points to the model surface less the shape tolerance (see
    `_shape_residual`), at least 0: what an accepted object claims as its own (plain distance when
    the tolerance is off)."""
    tau = shape_tolerance_m(model, params)
    d = model.distance(pts_canonical)
    return np.maximum(d - tau, 0.0) if tau > 0 else d


def score_hypothesis(model, views: CoverageViews, R, t, scene: SceneIndex, params: dict, rmse_max_m: float,
                     occluders=()) -> Hypothesis:
    """Score the pose (R (3,3), t (3,) m: canonical -> local scene frame) of `model` against `scene`.

    views: the class's template views thinned to coverage_voxel_m (`view_points`, prepared by
    `CoverageViews.of`), for upright poses.
    rmse_max_m: the class's RMSE limit (m). occluders: boxes [x,y,z,l,w,h,yaw] of accepted objects;
    template points hidden under them are not asked for (f_t counts only the others). Returns a
    Hypothesis with the scores filled in (score 0 when no candidate point exists); the thresholds are
    the `params` keys named in the module doc and in `params.DESCRIPTIONS`.
    """
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    box = canonical_box(model.vertices, t, matrix_to_quat(R), model.symmetry_order)
    h = Hypothesis(cls=model.cls, R=R, t=t, box=box)
    reach = 0.5 * np.hypot(box[3], box[4]) + params["score_reach_margin_m"]
    near = np.asarray(scene.tree_xy.query_ball_point(box[:2], reach), dtype=np.int64)
    if len(near) == 0:
        return h
    near.sort()
    inbox = points_in_box(scene.pts[near], box, params["candidate_box_margin_m"])
    cand = near[inbox]
    if len(cand) == 0:
        return h
    _overhang(h, scene, near, params)
    d, h.shape_offset_m = _shape_residual(model, (scene.pts[cand] - t) @ R, params)
    inl = d < params["inlier_m"]
    h.cand, h.inl = cand, inl
    h.rmse_m = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else 1.0  # no inlier: 1 m, beyond any rmse_max
    h.upright = up_tilt_rad(model, R) <= np.deg2rad(params["upright_tilt_max_deg"])
    # Coverage against the scene points (seabed included) around the object, in a small local tree.
    local = scene.all_tree_xy.query_ball_point(box[:2], reach + params["coverage_m"])
    if len(local) > 0:
        around = scene.all_xyz[np.sort(np.asarray(local, dtype=np.int64))]
        local_pts = around[np.abs(around[:, 2] - box[2]) <= 0.5 * box[5] + params["coverage_z_band_m"]]
        if len(local_pts) > 0:
            grid = NearGrid(local_pts, params["coverage_m"])
            shadow = ShadowMap(around, params["shadow_cell_m"], params["shadow_margin_m"]) \
                if params["shadow_margin_m"] > 0 else None
            h.f_t = (_coverage_upright(views, R, t, grid, occluders, params, h.shape_offset_m, shadow)
                     if h.upright else
                     _coverage_virtual(model, R, t, grid, occluders, params, h.shape_offset_m, shadow))
    rescore(h, scene.active, rmse_max_m, params)
    return h


def rescore(h: Hypothesis, active: np.ndarray, rmse_max_m: float, params: dict) -> float:
    """Recompute f_s, g_h and the score of `h` given which candidate points are still unexplained."""
    if len(h.cand) == 0:
        h.f_s, h.score = 0.0, 0.0
        return 0.0
    a = active[h.cand]
    n_act = int((a if h.cand_free is None else a & h.cand_free).sum())
    h.f_s = float((h.inl & a).sum() / n_act) if n_act else 0.0
    q = max(0.0, 1.0 - (h.rmse_m / rmse_max_m) ** 2)
    h.g_h = height_consistency(h, active, params)
    h.score = float(h.f_t * h.f_s * q * h.g_h)
    return h.score


def new_fraction(h: Hypothesis, active: np.ndarray) -> float:
    """Share of the hypothesis' inliers not yet explained by accepted objects (0 without inliers)."""
    n = int(h.inl.sum())
    if n == 0:
        return 0.0
    return float((h.inl & active[h.cand]).sum() / n)
