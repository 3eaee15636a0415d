"""Procedural, watertight triangle meshes of the four reef element classes (their specs, defaults and
the dispatch by class name: :mod:`sonardet.objects.classes`).

Every mesh is built in its canonical frame: z up, the vertical symmetry axis (through the tetrapod's
hub, the cone's and the ring's axis) at x = y = 0, the lowest point at z = 0, canonical yaw 0, and
it stands in its resting pose (tetrapod on three legs, cone and ring on their base). Dimensions in
metres. Solids are built from primitives with exact booleans (manifold3d), which always return closed
2-manifolds; trimesh alone cannot guarantee that for boolean results. The booleans run in float64
(manifold3d's ``Mesh64``) and the cutters are united before they are subtracted: in float32 (trimesh's
manifold engine) the union of legs and hub and the cut-outs left places where the solid touches itself
along an edge, a topological 2-manifold only while the coincident vertices are kept apart (edges of four
faces once a reader merges them); and subtracting overlapping cutters as one concatenated mesh gave
manifold3d an invalid (self-intersecting) operand.

Each builder returns an :class:`ObjectModel`: the mesh, the convex parts used by the physics engine
(each a vertex array whose convex hull is part of the solid), the specification volume it must match
and the rotational symmetry about z.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import manifold3d
import numpy as np
import trimesh

#: Symmetry order about the canonical z axis: 0 = continuous (any yaw), n = n-fold.
SYMMETRY_CONTINUOUS = 0


@dataclass
class ObjectModel:
    """A built object: mesh in the canonical frame plus what the simulator and detectors need."""

    cls: str
    mesh: trimesh.Trimesh
    convex_parts: list[np.ndarray]
    spec_volume_m3: float
    symmetry_order: int
    spec: dict = field(default_factory=dict)


def _frustum(r0: float, r1: float, length: float, sections: int) -> trimesh.Trimesh:
    """Solid truncated cone along +z from z=0 (radius r0) to z=length (radius r1)."""
    profile = np.array([[0.0, 0.0], [r0, 0.0], [r1, length], [0.0, length], [0.0, 0.0]])
    return trimesh.creation.revolve(profile, sections=sections)


def _align_z_to(direction) -> np.ndarray:
    """4x4 rotation taking +z onto the unit vector `direction`."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    return trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d)


def _to_manifold(mesh: trimesh.Trimesh) -> manifold3d.Manifold:
    """A closed trimesh as a manifold3d solid, in float64 (manifold3d's Mesh64)."""
    solid = manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        tri_verts=np.ascontiguousarray(mesh.faces, dtype=np.uint64)))
    if solid.status() != manifold3d.Error.NoError:
        raise ValueError(f"mesh primitive is not a closed 2-manifold ({solid.status()})")
    return solid


def _from_manifold(solid: manifold3d.Manifold) -> trimesh.Trimesh:
    """The triangle mesh of a manifold3d solid (float64 vertices, faces as manifold3d gives them)."""
    out = solid.to_mesh64()
    # Copies: manifold3d's arrays are read-only views, and Open3D refuses read-only input.
    return trimesh.Trimesh(vertices=np.array(out.vert_properties, dtype=np.float64)[:, :3].copy(),
                           faces=np.array(out.tri_verts, dtype=np.int64), process=False)


def _union(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Union of closed meshes in float64 (manifold3d batch boolean)."""
    return _from_manifold(manifold3d.Manifold.batch_boolean([_to_manifold(m) for m in meshes], manifold3d.OpType.Add))


def _difference(a: trimesh.Trimesh, cutters: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """`a` minus the union of the cutters (which may overlap one another), in float64."""
    if not cutters:
        return a
    cut = manifold3d.Manifold.batch_boolean([_to_manifold(m) for m in cutters], manifold3d.OpType.Add)
    return _from_manifold(_to_manifold(a) - cut)


def tetrapod_leg_directions() -> np.ndarray:
    """Unit axes (4,3) of a tetrapod standing on three legs: one up, three at -1/3 in z, first along +x."""
    s = np.sqrt(8.0 / 9.0)
    ang = np.deg2rad([0.0, 120.0, 240.0])
    down = np.stack([s * np.cos(ang), s * np.sin(ang), np.full(3, -1.0 / 3.0)], 1)
    return np.vstack([[0.0, 0.0, 1.0], down])


def _tetrapod_parts(height_m: float, root_ratio: float, taper: float, sections: int):
    """Legs and hub of a tetrapod of overall height height_m; root radius = root_ratio * leg length."""
    # Height from the lowest rim of a down leg's end disc to the top of the up leg:
    # H = L + L/3 + r1 * sin(angle of the disc normal from vertical) = L (4/3 + taper*a*sqrt(8/9)).
    leg_len = height_m / (4.0 / 3.0 + taper * root_ratio * np.sqrt(8.0 / 9.0))
    r0 = root_ratio * leg_len
    r1 = taper * r0
    parts = []
    for d in tetrapod_leg_directions():
        leg = _frustum(r0, r1, leg_len, sections)
        leg.apply_transform(_align_z_to(d))
        parts.append(leg)
    hub = trimesh.creation.icosphere(subdivisions=3, radius=r0)
    parts.append(hub)
    return parts, leg_len, r0, r1


def build_tetrapod(cls: str, height_m: float, mass_kg: float, density_kg_m3: float, taper: float = 0.6,
                   sections: int = 48) -> ObjectModel:
    """Tetrapod (Neyrpic-like): four tapered legs at tetrahedral angles from a common hub.

    The leg thickness is solved (bisection on root radius / leg length) so that the solid's volume
    equals mass_kg / density_kg_m3 within 0.1 %; the overall height is exact by construction.
    """
    target = mass_kg / density_kg_m3

    def volume(a):
        parts, *_ = _tetrapod_parts(height_m, a, taper, sections)
        return _union(parts).volume

    lo, hi = 0.05, 0.7
    if not (volume(lo) < target < volume(hi)):
        raise ValueError(
            f"{cls}: no tetrapod of height {height_m} m has volume {target:.3f} m^3 "
            f"(mass {mass_kg} kg at {density_kg_m3} kg/m^3); check objects.{cls}.height_m and mass_kg"
        )
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if volume(mid) < target:
            lo = mid
        else:
            hi = mid
        if abs(hi - lo) < 1e-5:
            break
    a = 0.5 * (lo + hi)
    parts, leg_len, r0, r1 = _tetrapod_parts(height_m, a, taper, sections)
    mesh = _union(parts)
    shift = -mesh.bounds[0, 2]
    mesh.apply_translation([0.0, 0.0, shift])
    convex = [np.asarray(p.vertices) + [0.0, 0.0, shift] for p in parts]
    spec = {"height_m": height_m, "mass_kg": mass_kg, "leg_length_m": leg_len, "leg_root_radius_m": r0,
            "leg_tip_radius_m": r1, "taper": taper}
    return ObjectModel(cls, mesh, convex, target, 3, spec)


def _annulus_sectors(r_in: float, r_out: float, z0: float, z1: float, n: int, sections_per: int = 4):
    """Vertex sets of n angular sectors of a thick-walled cylinder (each nearly convex; physics only)."""
    parts = []
    for k in range(n):
        a = np.linspace(2 * np.pi * k / n, 2 * np.pi * (k + 1) / n, sections_per + 1)
        ring = np.concatenate([np.stack([r * np.cos(a), r * np.sin(a)], 1) for r in (r_in, r_out)])
        parts.append(np.vstack([np.c_[ring, np.full(len(ring), z0)], np.c_[ring, np.full(len(ring), z1)]]))
    return parts


def _radial_hole(radius: float, centre_r: float, z: float, angle: float, axis_rz, length: float,
                 sections: int) -> trimesh.Trimesh:
    """Cylinder cutter of the given radius through a wall: centre at (centre_r, angle, z), axis in the
    radial-vertical plane along axis_rz = (radial, vertical) components."""
    cyl = trimesh.creation.cylinder(radius=radius, height=length, sections=sections)
    ar, az = axis_rz
    axis = np.array([ar * np.cos(angle), ar * np.sin(angle), az])
    cyl.apply_transform(_align_z_to(axis))
    cyl.apply_translation([centre_r * np.cos(angle), centre_r * np.sin(angle), z])
    return cyl


#: Bands the cone's slant walls are split into (rings of vertices on the same surface). Without them
#: each wall facet is one quad from base to top, and the boolean triangulates a facet pierced by holes
#: of three rows into slivers spanning the rows; Open3D's triangle-triangle test calls such coplanar
#: slivers self-intersecting (its `is_watertight` then fails) although the solid is closed.
_CONE_WALL_BANDS = 8


def _split_slopes(profile: np.ndarray, n: int) -> np.ndarray:
    """A closed (r, z) profile with every non-horizontal edge split into `n` equal segments (the same
    polygon, more vertices)."""
    pts = []
    for a, b in zip(profile[:-1], profile[1:]):
        k = n if abs(b[1] - a[1]) > 0 else 1
        pts += [a + (b - a) * i / k for i in range(k)]
    return np.array(pts + [profile[-1]])


def build_reef_cone(height_m: float, base_diameter_m: float, top_diameter_m: float, wall_m: float,
                    n_holes: int, hole_diameter_m: tuple[float, float], holes: bool, hole_seed: int,
                    sections: int = 96) -> ObjectModel:
    """Hollow truncated cone open at both ends, wall thickness wall_m normal to the slant surface,
    with n_holes round holes (diameters uniform in hole_diameter_m) through the wall in staggered rows.

    The hole layout is drawn from hole_seed, so the class shape is fixed by the config.
    """
    rb, rt = 0.5 * base_diameter_m, 0.5 * top_diameter_m
    slope = (rb - rt) / height_m  # dr/dz of the outer surface
    cos_a = 1.0 / np.hypot(1.0, slope)  # cosine of the wall's angle from vertical
    t_h = wall_m / cos_a  # horizontal wall thickness
    if t_h >= rt:
        raise ValueError(
            f"reef_cone: wall {wall_m} m is too thick for a top diameter of {top_diameter_m} m; "
            "increase objects.reef_cone.top_diameter_m or reduce wall_m"
        )
    profile = np.array([[rb - t_h, 0.0], [rb, 0.0], [rt, height_m], [rt - t_h, height_m], [rb - t_h, 0.0]])
    shell = trimesh.creation.revolve(_split_slopes(profile, _CONE_WALL_BANDS), sections=sections)
    # Pappus: volume = 2 pi * area * centroid radius of the profile (a trapezoid, here a parallelogram).
    spec_volume = 2 * np.pi * t_h * height_m * (0.5 * (rb + rt) - 0.5 * t_h)
    mesh = shell
    hole_list = []
    if holes and n_holes > 0:
        rng = np.random.default_rng(hole_seed)
        # Rows at fractions of the height; each row holds a share proportional to its circumference.
        fracs = np.array([0.2, 0.48, 0.76])
        radii = rb - slope * fracs * height_m
        counts = np.floor(n_holes * radii / radii.sum()).astype(int)
        counts[0] += n_holes - counts.sum()
        normal_rz = np.array([1.0, slope]) * cos_a  # outward normal of the slant wall (radial, vertical)
        cutters = []
        for row, (f, n) in enumerate(zip(fracs, counts)):
            z = f * height_m
            r_mid = rb - slope * z - 0.5 * t_h
            offset = rng.uniform(0, 2 * np.pi / n) + row * np.pi / n
            d = rng.uniform(hole_diameter_m[0], hole_diameter_m[1], n)
            for k in range(n):
                ang = offset + 2 * np.pi * k / n
                cutters.append(_radial_hole(0.5 * d[k], r_mid, z, ang, normal_rz, 4 * wall_m, 24))
                hole_list.append({"z_m": z, "angle_rad": float(ang), "diameter_m": float(d[k])})
                spec_volume -= np.pi * (0.5 * d[k]) ** 2 * wall_m
        mesh = _difference(shell, cutters)
    convex = []
    n_sec = 16
    for k in range(n_sec):
        a = np.linspace(2 * np.pi * k / n_sec, 2 * np.pi * (k + 1) / n_sec, 5)
        pts = []
        for r, z in profile[:-1]:
            pts.append(np.stack([r * np.cos(a), r * np.sin(a), np.full(len(a), z)], 1))
        convex.append(np.vstack(pts))
    spec = {"height_m": height_m, "base_diameter_m": base_diameter_m, "top_diameter_m": top_diameter_m,
            "wall_m": wall_m, "holes": hole_list}
    return ObjectModel("reef_cone", mesh, convex, float(spec_volume), SYMMETRY_CONTINUOUS, spec)


def build_reef_ring(height_m: float, outer_diameter_m: float, outer_wall_m: float, inner_wall_m: float,
                    gap_m: float, outer_holes_n: int, outer_hole_diameter_m: float, inner_holes_n: int,
                    inner_hole_diameter_m: float, n_ribs: int, rib_m: float, holes: bool,
                    sections: int = 128) -> ObjectModel:
    """Double-walled concrete ring: two concentric walls with a gap, joined by n_ribs radial ribs,
    holes at mid-height through each wall (outer holes at 22.5 deg + k*360/n, inner at 15 deg +
    k*360/n, ribs at k*360/n_ribs, so that no hole meets a rib for the default counts)."""
    ro = 0.5 * outer_diameter_m
    r_oi = ro - outer_wall_m  # inner face of the outer wall
    r_io = r_oi - gap_m  # outer face of the inner wall
    r_ii = r_io - inner_wall_m
    if r_ii <= 0:
        raise ValueError(
            "reef_ring: walls and gap do not fit in the diameter; reduce objects.reef_ring.gap_m or the walls"
        )
    outer = trimesh.creation.annulus(r_min=r_oi, r_max=ro, height=height_m, sections=sections)
    inner = trimesh.creation.annulus(r_min=r_ii, r_max=r_io, height=height_m, sections=sections)
    parts = [outer, inner]
    rib_len = gap_m + 0.5 * (outer_wall_m + inner_wall_m)
    rib_mid = 0.5 * (r_oi + r_io)
    rib_angles = 2 * np.pi * np.arange(n_ribs) / max(n_ribs, 1)
    for ang in rib_angles:
        rib = trimesh.creation.box(extents=[rib_len, rib_m, height_m])
        rib.apply_transform(trimesh.transformations.rotation_matrix(ang, [0, 0, 1]))
        rib.apply_translation([rib_mid * np.cos(ang), rib_mid * np.sin(ang), 0.0])
        parts.append(rib)
    solid = _union(parts)
    solid.apply_translation([0.0, 0.0, 0.5 * height_m])
    spec_volume = np.pi * height_m * ((ro**2 - r_oi**2) + (r_io**2 - r_ii**2)) + n_ribs * gap_m * rib_m * height_m
    cutters = []
    if holes:
        for n, dia, r_out, r_in, offset in (
            (outer_holes_n, outer_hole_diameter_m, ro, r_oi, np.deg2rad(22.5)),
            (inner_holes_n, inner_hole_diameter_m, r_io, r_ii, np.deg2rad(15.0)),
        ):
            for k in range(n):
                ang = offset + 2 * np.pi * k / n
                cutters.append(_radial_hole(0.5 * dia, 0.5 * (r_out + r_in), 0.5 * height_m, ang, (1.0, 0.0),
                                            3 * (r_out - r_in), 32))
                # A round hole through a cylindrical wall removes about pi r^2 t.
                spec_volume -= np.pi * (0.5 * dia) ** 2 * (r_out - r_in)
    mesh = _difference(solid, cutters)
    convex = _annulus_sectors(r_oi, ro, 0.0, height_m, 16) + _annulus_sectors(r_ii, r_io, 0.0, height_m, 12)
    for ang in rib_angles:
        c, s = np.cos(ang), np.sin(ang)
        corners = np.array([[u, v, z] for u in (r_io, r_oi) for v in (-0.5 * rib_m, 0.5 * rib_m)
                            for z in (0.0, height_m)])
        convex.append(np.c_[corners[:, 0] * c - corners[:, 1] * s, corners[:, 0] * s + corners[:, 1] * c,
                            corners[:, 2]])
    spec = {"height_m": height_m, "outer_diameter_m": outer_diameter_m, "outer_wall_m": outer_wall_m,
            "inner_wall_m": inner_wall_m, "gap_m": gap_m, "n_ribs": n_ribs}
    return ObjectModel("reef_ring", mesh, convex, float(spec_volume), SYMMETRY_CONTINUOUS, spec)


def build_tetrapod_variant(cls: str, height_m: float, root_ratio: float, taper: float, sections: int,
                           leg_scale: float = 1.0, short_leg: int | None = None, short_frac: float = 0.0,
                           rounded: bool = False) -> ObjectModel:
    """A tetrapod unlike its class model (for model-mismatch scenes): the leg root radius / leg length
    `root_ratio` times `leg_scale` (thinner or thicker legs at the same overall height), optionally
    one down leg (`short_leg` 1-3) shortened by `short_frac` of its length (broken) and the leg ends
    rounded (a sphere of the tip radius inside each end, so no leg gets longer). Canonical frame as every object (lowest point at
    z = 0); its symmetry order stays 3 (the class's)."""
    parts, leg_len, r0, r1 = _tetrapod_parts(height_m, root_ratio * leg_scale, taper, sections)
    dirs = tetrapod_leg_directions()
    if short_leg is not None and short_frac > 0:
        length = leg_len * (1.0 - short_frac)
        leg = _frustum(r0, r0 + (r1 - r0) * (1.0 - short_frac), length, sections)
        leg.apply_transform(_align_z_to(dirs[short_leg]))
        parts[short_leg] = leg
    if rounded:
        for k, d in enumerate(dirs):
            reach = leg_len * (1.0 - short_frac) if k == short_leg else leg_len
            tip_r = r1 if k != short_leg else r0 + (r1 - r0) * (1.0 - short_frac)
            tip = trimesh.creation.icosphere(subdivisions=2, radius=tip_r)
            tip.apply_translation(np.asarray(d) * (reach - tip_r))  # rounds the end, no longer leg
            parts.append(tip)
    mesh = _union(parts)
    shift = -mesh.bounds[0, 2]
    mesh.apply_translation([0.0, 0.0, shift])
    # The physics takes the legs and the hub (the rounded ends, inside the legs' reach, add nothing but
    # collision cost).
    convex = [np.asarray(p.vertices) + [0.0, 0.0, shift] for p in parts[:5]]
    spec = {"height_m": height_m, "leg_length_m": leg_len, "leg_root_radius_m": r0, "leg_tip_radius_m": r1,
            "taper": taper, "leg_scale": leg_scale, "short_leg": short_leg, "short_frac": short_frac,
            "rounded": rounded}
    return ObjectModel(cls, mesh, convex, float(mesh.volume), 3, spec)
