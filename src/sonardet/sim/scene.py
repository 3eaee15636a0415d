"""Scene synthesis: seabed, rocks, physically settled reef elements, an MBES survey, annotations.

Frames and units: scene frame (x east, y north, z up, metres); the transducer runs at
`survey.transducer_z_m` (default 0) over a seabed near `seabed.mean_depth_m`. The scene rectangle
is [0, extent_x] x [0, extent_y]; the seabed mesh extends beyond it so outer beams see seabed.

Steps (each with its own seed derived from the config seed and the scene id):
1. seabed heightfield (fBm), 2. layout of the objects per class, 3. rocks (static clutter, partly
buried), 4. MuJoCo settling of the objects (rocks act as fixed obstacles), optionally followed by
burial in the sediment (`scenes.realism.burial_m`), 5. survey lines along x, y or both, 6. Embree
ray casting, per line only against the geometry inside its swath ("model only what the scene
needs"), with the sensor's optional realism profile (`sensor.realism`), 7. annotations: pose, box,
number of soundings, visibility. The scene files are read and written by `sonardet.io.scenes`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from .. import SCHEMA_VERSION
from ..seeds import config_hash, derive_seed
from ..geometry import quat_from_yaw, quat_to_matrix
from ..objects import ObjectInfo
from ..objects.catalog import canonical_box
from ..objects.perturb import draw_perturbation, perturbed_object
from .layout import FENCE_CLEARANCE_M, Fence, plan_layout
from .mbes import RaycastTarget, SensorConfig, Soundings, scan, survey_lines, swath_half_width_m
from .effects import swath_margin_m
from .effects.burial import bury_objects as bury_settled
from .physics import RigidBody, settle
from .rocks import make_rock
from .seabed import make_seabed

log = logging.getLogger(__name__)

SEABED_ID = -2
ROCK_ID = -3


@dataclass
class Scene:
    """A synthesized scene: soundings (xyz float64 (N,3), ping, beam, line, label = object index or -1)
    and its metadata (the JSON contract of DESIGN.md section 3); `sonardet.io.scenes.write_scene` writes it."""

    xyz: np.ndarray
    ping: np.ndarray
    beam: np.ndarray
    line: np.ndarray
    label: np.ndarray
    meta: dict = field(default_factory=dict)
    #: The settled layout (:func:`settled_state`): what a variant of this scene whose config differs
    #: only after the physics reuses instead of settling again. Not part of the scene files.
    settled: dict = field(default_factory=dict)


def class_counts(cfg: dict, classes: list[str], rng) -> dict:
    """Objects per class of one scene: a total drawn from `cfg["n_objects"]` split by `cfg["class_mix"]`."""
    n = int(rng.integers(cfg["n_objects"][0], cfg["n_objects"][1] + 1))
    mix = np.array([cfg["class_mix"].get(c, 0.0) for c in classes], dtype=np.float64)
    if mix.sum() <= 0:
        raise ValueError("scenes.class_mix gives zero weight to every configured class")
    counts = rng.multinomial(n, mix / mix.sum())
    return {c: int(k) for c, k in zip(classes, counts)}


def _swath_rect(traj, line: int, half_width: float, margin: float):
    pos = traj.position[traj.line == line]
    heading = traj.heading_rad[traj.line == line][0]
    along_x = abs(np.cos(heading)) > 0.5
    lo, hi = pos[:, :2].min(0), pos[:, :2].max(0)
    if along_x:
        return lo[0] - margin, hi[0] + margin, lo[1] - half_width - margin, hi[1] + half_width + margin
    return lo[0] - half_width - margin, hi[0] + half_width + margin, lo[1] - margin, hi[1] + margin


def _overlaps(bounds_xy, rect) -> bool:
    (x0, y0), (x1, y1) = bounds_xy
    return not (x1 < rect[0] or x0 > rect[1] or y1 < rect[2] or y0 > rect[3])


def simulate_scene(scene_id: str, config: dict, objects: dict[str, ObjectInfo], cull: bool | None = None,
                   settled: dict | None = None) -> Scene:
    """Synthesize one scene from the validated config and the class models. Deterministic for a
    (config, scene_id) pair. cull overrides `scenes.cull_to_swath` (benchmarks compare both).
    settled: this scene's settled layout (:func:`apply_settled`), applied instead of the physics."""
    sc = config["scenes"]
    seed = derive_seed(config["seed"], "scene", scene_id)
    rngs = {k: np.random.default_rng(derive_seed(seed, k)) for k in
            ("seabed", "layout", "rocks", "physics", "survey", "sensor")}
    timings = {}
    ex, ey = sc["extent_m"]
    extent = (0.0, float(ex), 0.0, float(ey))
    sensor = SensorConfig.from_dict(config["sensor"])
    sb = sc["seabed"]
    sv = sc["survey"]
    altitude = _altitude_m(sb, sv)

    t0 = time.perf_counter()
    hf = _make_seabed(sb, (ex, ey), rngs["seabed"])
    timings["seabed_s"] = time.perf_counter() - t0

    # Layout, then rocks: static clutter, partly buried, away from the objects' spawn footprints.
    t0 = time.perf_counter()
    spawns, unplaced, radius = layout_objects(scene_id, config, objects, sc, extent, hf, rngs["layout"])
    rocks, rock_meta = _place_rocks(scene_id, sc, spawns, radius, hf, rngs["rocks"])
    timings["layout_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    own = mismatch_objects(spawns, objects, sc.get("mismatch"), config["objects"], seed)
    if own is not None:
        timings["mismatch_s"] = time.perf_counter() - t0

    # Physics, then burial: settled objects sink into the sediment (the physics knows no sediment).
    t0 = time.perf_counter()
    if settled is None:
        kept, removed, phys, rocks = _settle_scene(scene_id, spawns, objects, hf, sc, rngs["physics"], extent, rocks,
                                                   rock_meta, timings, own)
    else:
        kept, removed, phys, rocks = apply_settled(settled, scene_id, config, spawns, rocks, rock_meta, timings)
    timings["physics_s"] = time.perf_counter() - t0
    state = settled_state(scene_id, config, spawns, kept, removed, phys, rock_meta)  # before the burial
    burial_m = (sc.get("realism") or {}).get("burial_m", [0.0, 0.0])
    kept, buried = bury_objects(kept, spawns, burial_m, np.random.default_rng(derive_seed(seed, "burial")))

    # Survey and scan.
    t0 = time.perf_counter()
    direction = str(rngs["survey"].choice(sv["directions"]))
    traj = survey_lines(extent, direction, sv["transducer_z_m"], altitude, sv["overlap"], sensor,
                        run_in_m=sv["run_in_m"])
    posed = _posed_meshes(kept, spawns, objects, own)
    rocks = [m.copy().apply_translation(pos) for m, pos in rocks]
    do_cull = sc["cull_to_swath"] if cull is None else cull
    snd, n_tri = _scan_survey(traj, hf, posed, rocks, sensor, sv["transducer_z_m"], do_cull, rngs["sensor"])
    inside = (snd.xyz[:, 0] >= 0) & (snd.xyz[:, 0] <= ex) & (snd.xyz[:, 1] >= 0) & (snd.xyz[:, 1] <= ey)
    timings["scan_s"] = time.perf_counter() - t0
    label = np.where(snd.mesh >= 0, snd.mesh, -1).astype(np.int32)[inside]

    objs = annotate_objects(kept, spawns, objects, label, sc["min_points_visible"], buried, own)
    meta = {
        "schema_version": SCHEMA_VERSION,
        "scene": scene_id,
        "seed": int(seed),
        "config_hash": config_hash({k: config[k] for k in ("seed", "classes", "objects", "sensor", "scenes")}),
        "extent": list(extent),
        "survey": {"direction": direction, "n_lines": int(len(np.unique(traj.line))), "n_pings": int(len(traj)),
                   "altitude_m": float(altitude)},
        "seabed": {"mean_depth_m": sb["mean_depth_m"], "cell_m": sb["cell_m"]},
        "objects": objs,
        "removed": removed,
        "unplaced": unplaced,
        "rocks": rock_meta,
        "physics": phys,
        "stats": {"n_points": int(inside.sum()), "n_rays": int(snd.n_rays), "n_dropped": int(snd.n_dropped),
                  "triangles_cast": int(n_tri), "culled": bool(do_cull),
                  "points_per_m2": float(inside.sum() / (ex * ey))},
        "timings_s": timings,
    }
    return Scene(snd.xyz[inside], snd.ping[inside], snd.beam[inside], snd.line[inside], label, meta, state)


def settled_key(scene_id: str, config: dict) -> str:
    """Hash of what a scene's settled layout depends on: the scene id and the config's seed, classes,
    objects, sensor and scenes sections without their realism parts (`sensor.realism` and
    `scenes.realism` act after the physics: burial, sensor effects)."""
    return config_hash({
        "scene": scene_id,
        **{k: config[k] for k in ("seed", "classes", "objects")},
        **{k: {kk: vv for kk, vv in config[k].items() if kk != "realism"} for k in ("sensor", "scenes")},
    })


def settled_state(scene_id: str, config: dict, spawns, kept, removed: list, phys: dict, rock_meta: list) -> dict:
    """The settled layout of a scene as JSON-ready data: its key (:func:`settled_key`), every spawn's
    pose (t (3,) m, q (4,) w,x,y,z) and layer after the physics, the kept objects [(spawn index, t, q)],
    the removed ones, the physics summary and the rocks the physics rejected. Floats are kept exact
    (JSON writes the shortest repr that reads back to the same float64)."""
    return {
        "scene": scene_id,
        "key": settled_key(scene_id, config),
        "spawns": [{"t": [float(v) for v in sp.t], "q": [float(v) for v in sp.q], "layer": int(sp.layer)}
                   for sp in spawns],
        "kept": [{"spawn": int(k), "t": [float(v) for v in t], "q": [float(v) for v in q]} for k, t, q in kept],
        "removed": removed,
        "physics": phys,
        "rocks_removed": [k for k, r in enumerate(rock_meta) if r.get("removed")],
    }


def apply_settled(settled: dict, scene_id: str, config: dict, spawns, rocks: list, rock_meta: list,
                  timings: dict | None = None):
    """Put a scene's spawns into the settled layout `settled` (:func:`settled_state` of the same
    scene under a config with the same :func:`settled_key`, e.g. the synthetic scene a realism
    variant shares its seeds with) instead of running the physics, which gives the same scene: spawn
    poses and layers, rejected rocks flagged and left out; `timings` gets ``physics_reused`` 1.
    Returns (kept, removed, physics summary, remaining rocks) like the physics step. ValueError when
    the key or the spawn count differs."""
    key = settled_key(scene_id, config)
    if settled.get("key") != key or settled.get("scene") != scene_id:
        raise ValueError(
            f"settled layout of scene {settled.get('scene')!r} (key {settled.get('key')}) does not belong to scene "
            f"{scene_id!r} under this config (key {key}): its seed, classes, objects, sensor or scenes settings "
            "differ beyond their realism parts; simulate the scene without it"
        )
    if len(settled["spawns"]) != len(spawns):
        raise ValueError(f"settled layout of scene {scene_id!r} has {len(settled['spawns'])} spawns, the layout "
                         f"{len(spawns)}: it was made by another version of the simulator; simulate without it")
    for sp, st in zip(spawns, settled["spawns"]):
        sp.t = np.array(st["t"], dtype=np.asarray(sp.t).dtype)
        sp.q = np.array(st["q"], dtype=np.asarray(sp.q).dtype)
        sp.layer = int(st["layer"])
    kept = [(int(e["spawn"]), np.array(e["t"], dtype=np.float64), np.array(e["q"], dtype=np.float64))
            for e in settled["kept"]]
    gone = set(settled["rocks_removed"])
    for k in gone:
        rock_meta[k]["removed"] = True
    rocks = [r for k, r in enumerate(rocks) if k not in gone]
    if timings is not None:
        timings["physics_reused"] = 1.0
    log.info("%s: settled layout reused (%d objects kept, %d removed by the physics)", scene_id, len(kept),
             len(settled["removed"]))
    return kept, [dict(r) for r in settled["removed"]], dict(settled["physics"]), rocks


def _altitude_m(seabed: dict, survey: dict) -> float:
    """The transducer's height above the mean seabed (m); ValueError when the seabed is not below it."""
    altitude = survey["transducer_z_m"] - seabed["mean_depth_m"]
    if altitude <= 0:
        raise ValueError(
            f"scenes.seabed.mean_depth_m ({seabed['mean_depth_m']} m) must lie below scenes.survey.transducer_z_m "
            f"({survey['transducer_z_m']} m)"
        )
    return altitude


def _make_seabed(sb: dict, extent_m, rng: np.random.Generator):
    """The scene's seabed heightfield from the `scenes.seabed` settings (slope, azimuth and amplitude
    drawn from rng first, then the fBm)."""
    return make_seabed(
        extent_m=extent_m, cell_m=sb["cell_m"], mean_depth_m=sb["mean_depth_m"],
        slope_deg=rng.uniform(*sb["slope_deg"]), slope_azimuth_deg=rng.uniform(0, 360),
        amplitude_m=rng.uniform(*sb["amplitude_m"]), base_wavelength_m=sb["base_wavelength_m"],
        octaves=sb["octaves"], persistence=sb["persistence"], roughness_m=sb["roughness_m"],
        margin_m=sb["margin_m"], rng=rng,
    )


def class_geometry(objects: dict[str, ObjectInfo]):
    """Per class: vertices (V, 3) of its mesh (canonical frame, m), horizontal radius (m) about its
    vertical axis and height (m), as the layout needs them."""
    verts = {c: np.asarray(o.mesh.vertices) for c, o in objects.items()}
    radius = {c: float(np.max(np.hypot(v[:, 0], v[:, 1]))) for c, v in verts.items()}
    height = {c: float(o.extents_m[2]) for c, o in objects.items()}
    return verts, radius, height


def layout_objects(scene_id: str, config: dict, objects: dict[str, ObjectInfo], sc: dict, extent, hf,
                   rng: np.random.Generator):
    """The planned spawns of one scene (counts per class drawn from `scenes`, then the layout) inside
    extent (xmin, xmax, ymin, ymax) m on the seabed hf. Returns (spawns, unplaced messages, class
    radius (m) by class); unplaced objects are logged."""
    # The layout draws per class in the config's order, whatever the order of `objects`.
    classes = [c for c in config["classes"] if c in objects] + [c for c in objects if c not in config["classes"]]
    counts = class_counts(sc, classes, rng) if classes else {}
    verts, radius, height = class_geometry(objects)
    spawns, unplaced = plan_layout(counts, radius, height, verts, extent, sc,
                                   lambda x, y: float(hf.height_at(x, y)), rng)
    for msg in unplaced:
        log.warning("%s: %s", scene_id, msg)
    return spawns, unplaced, radius


def _place_rocks(scene_id: str, sc: dict, spawns, radius: dict, hf, rng: np.random.Generator):
    """Rocks (static clutter, partly buried) at random spots clear of the spawn footprints. Returns
    (rocks [(trimesh in its frame, position (3,) m)], rock metadata [{size_m, pos}])."""
    ex, ey = sc["extent_m"]
    n_rocks = int(rng.integers(sc["n_rocks"][0], sc["n_rocks"][1] + 1))
    rocks, rock_meta = [], []
    spawn_xy = np.array([s.t[:2] for s in spawns]) if spawns else np.zeros((0, 2))
    spawn_r = np.array([radius[s.cls] for s in spawns])
    fences = _fences(spawns)
    if fences:  # a dumped pile slumps beyond its elements' spawn spots: keep rocks off the whole fence
        spawn_xy = np.vstack([spawn_xy, [[f.x, f.y] for f in fences]])
        spawn_r = np.concatenate([spawn_r, [f.radius_m + FENCE_CLEARANCE_M for f in fences]])
    for k in range(n_rocks):
        size = float(np.exp(rng.uniform(np.log(sc["rock_size_m"][0]), np.log(sc["rock_size_m"][1]))))
        mesh = make_rock(size, rng)
        for _ in range(200):
            x, y = rng.uniform(0, ex), rng.uniform(0, ey)
            if len(spawn_xy) == 0 or np.all(np.hypot(*(spawn_xy - [x, y]).T) > spawn_r + 0.6 * size + 0.1):
                break
        else:
            log.warning("%s: no free spot for rock %d (%.2f m); not placed", scene_id, k, size)
            continue
        bury = sc["rock_burial"] * mesh.extents[2]
        z = float(hf.height_at(x, y)) - bury
        rocks.append((mesh, np.array([x, y, z])))
        rock_meta.append({"size_m": size, "pos": [x, y, z]})
    return rocks, rock_meta


def mismatch_objects(spawns, objects: dict[str, ObjectInfo], mismatch: dict | None, objects_cfg: dict, seed: int):
    """For a model-mismatch scene (`scenes.mismatch`), each spawn's own perturbed object and its draws
    [(ObjectInfo, record)] (sonardet.objects.perturb; draws seeded from the scene and the spawn);
    None for an ordinary scene."""
    if not mismatch:
        return None
    out = []
    for k, sp in enumerate(spawns):
        rec = draw_perturbation(sp.cls, mismatch["perturbations"], np.random.default_rng(derive_seed(seed, "mismatch", k)))
        out.append((perturbed_object(sp.cls, rec, objects_cfg, objects[sp.cls]), rec))
    return out


def _settle_scene(scene_id: str, spawns, objects, hf, sc: dict, rng: np.random.Generator, extent, rocks,
                  rock_meta: list, timings: dict, own=None):
    """Settle the spawns with the rocks as fixed obstacles (:func:`settle_spawns`); rocks the physics
    rejects are logged, flagged removed in rock_meta and left out. Returns (kept, removed, physics
    summary, remaining rocks); adds the physics timings to `timings`."""
    rock_bodies = [RigidBody(f"rock{k}", [np.asarray(m.vertices)], 1.0, pos, static=True)
                   for k, (m, pos) in enumerate(rocks)]
    t0 = time.perf_counter()
    gone = settle_dumps(scene_id, spawns, objects, hf, sc["physics"], rng, extent, own)
    if gone is not None:
        timings["dump_physics_s"] = time.perf_counter() - t0
    res, kept, removed, phys = settle_spawns(scene_id, spawns, objects, hf, sc["physics"], rng, extent, rock_bodies,
                                             own, skip=gone or {})
    for k, t, q in kept:
        if spawns[k].fence is not None:
            spawns[k].layer = _dump_layer(_geometry(k, spawns, objects, own), t, q, hf)
    if res is not None:
        gone_rocks = {int(rb.name[4:]) for rb in res.removed if rb.name.startswith("rock")}
        for k in sorted(gone_rocks):
            log.warning("%s: rock %d rejected by the physics (%s); not scanned", scene_id, k, "bad start")
            rock_meta[k]["removed"] = True
        rocks = [r for k, r in enumerate(rocks) if k not in gone_rocks]
        timings["physics_step_s"] = res.wall_time_s
        timings["physics_build_s"] = res.build_time_s
    return kept, removed, phys, rocks


def _geometry(k: int, spawns, objects: dict[str, ObjectInfo], own=None) -> ObjectInfo:
    """The object of spawn k: its own perturbed one in a mismatch scene, else its class model."""
    return own[k][0] if own is not None else objects[spawns[k].cls]


def _posed_meshes(kept, spawns, objects: dict[str, ObjectInfo], own=None):
    """[(vertices (V, 3) in the scene frame, faces (F, 3), object index)] of the kept objects."""
    posed = []
    for idx, (k, t, q) in enumerate(kept):
        obj = _geometry(k, spawns, objects, own)
        v = obj.mesh.vertices @ quat_to_matrix(q).T + t
        posed.append((v, np.asarray(obj.mesh.faces), idx))
    return posed


def _scan_survey(traj, hf, posed, rocks, sensor: SensorConfig, transducer_z_m: float, do_cull: bool,
                 rng: np.random.Generator):
    """Scan every survey line of traj against the seabed, the posed objects (mesh id = object index)
    and the rocks; with do_cull each line only against the geometry inside its swath (plus the margin
    the realism profile needs). Returns (soundings, triangles cast)."""
    zmin = float(hf.z.min())
    half = swath_half_width_m(sensor, transducer_z_m - zmin)
    cull_margin = 1.0 + swath_margin_m(sensor.realism, transducer_z_m - zmin,
                                       np.deg2rad(0.5 * sensor.swath_deg), sensor.sound_speed_mps)
    parts, n_tri = [], 0
    full_target = None
    for ln in np.unique(traj.line):
        sel = traj.line == ln
        sub = type(traj)(traj.position[sel], traj.heading_rad[sel], traj.line[sel])
        if do_cull:
            target = _culled_target(hf, posed, rocks, _swath_rect(traj, ln, half, cull_margin))
        else:
            if full_target is None:
                meshes = [(hf.vertices(), hf.faces())] + [(v, f) for v, f, _ in posed] + \
                         [(m.vertices, m.faces) for m in rocks]
                ids = [SEABED_ID] + [idx for _, _, idx in posed] + [ROCK_ID] * len(rocks)
                full_target = RaycastTarget(meshes, ids)
            target = full_target
        n_tri += target.n_triangles
        first_ping = int(np.flatnonzero(sel)[0])
        parts.append(scan(target, sub, sensor, rng, ping_offset=first_ping))
    return Soundings.concatenate(parts), n_tri


def _culled_target(hf, posed, rocks, rect) -> RaycastTarget:
    """The seabed cropped to rect (xmin, xmax, ymin, ymax) m and the objects and rocks overlapping it."""
    hfc = hf.crop(*rect)
    meshes = [(hfc.vertices(), hfc.faces())]
    ids = [SEABED_ID]
    for v, f, idx in posed:
        if _overlaps((v[:, :2].min(0), v[:, :2].max(0)), rect):
            meshes.append((v, f))
            ids.append(idx)
    for m in rocks:
        if _overlaps(m.bounds[:, :2], rect):
            meshes.append((m.vertices, m.faces))
            ids.append(ROCK_ID)
    return RaycastTarget(meshes, ids)


def _fences(spawns) -> list[Fence]:
    """The distinct fences of the dumped piles among the spawns, in spawn order."""
    return list({id(s.fence): s.fence for s in spawns if s.fence is not None}.values())


def _bodies(spawns, indices, objects: dict[str, ObjectInfo], own=None) -> list[RigidBody]:
    """Rigid bodies ``o{k}`` of the spawns k in `indices`, at their spawn poses."""
    out = []
    for k in indices:
        g = _geometry(k, spawns, objects, own)
        out.append(RigidBody(f"o{k}", g.convex_parts, g.mass_kg, spawns[k].t, spawns[k].q))
    return out


def _settle(bodies, hf, physics: dict, rng: np.random.Generator, bounds_xy, max_time_s: float):
    """:func:`settle` with the `scenes.physics` settings and the time limit max_time_s (s)."""
    return settle(bodies, hf, rng=rng, max_time_s=max_time_s, dt_s=physics["dt_s"],
                  lin_vel_tol=physics["lin_vel_tol"], ang_vel_tol=physics["ang_vel_tol"],
                  settle_window_s=physics["settle_window_s"], bounds_xy=bounds_xy, friction=physics["friction"],
                  sleep=physics["sleep"])


def _fence_bodies(fence: Fence, ground_z: float, tag: str, thickness_m: float = 0.2) -> list[RigidBody]:
    """Static panels (boxes, m) in a ring around fence's inner radius, from 0.5 m below the seabed at
    its centre (ground_z, m) to fence.height_m above it."""
    n = max(12, int(np.ceil(2 * np.pi * fence.radius_m / 0.8)))
    half_len = 1.1 * np.pi * (fence.radius_m + thickness_m) / n
    z0, z1 = ground_z - 0.5, ground_z + fence.height_m
    box = np.array([[x, y, z] for x in (-half_len, half_len) for y in (0.0, thickness_m) for z in (z0, z1)])
    out = []
    for i in range(n):
        a = 2 * np.pi * i / n
        # the panel's local y points outward from the centre; its inner face lies on the radius
        pos = [fence.x + fence.radius_m * np.cos(a), fence.y + fence.radius_m * np.sin(a), 0.0]
        out.append(RigidBody(f"fence{tag}_{i}", [box], 1.0, pos, quat_from_yaw(a - 0.5 * np.pi), static=True))
    return out


def _dump_layer(obj: ObjectInfo, t, q, hf) -> int:
    """Layer (0 = on the seabed) of a dumped pile's element at rest at (t (3,) m, q): how far the
    middle of its posed bounds is raised above where it would be on the seabed (half its height), in
    half object heights, rounded; 0-3. (Not its lowest point: a tetrapod on top of others often
    reaches down to the seabed with one leg.)"""
    v = np.asarray(obj.mesh.vertices) @ quat_to_matrix(q).T + t
    mid = 0.5 * (v.min(0) + v.max(0))
    half_h = 0.5 * float(np.ptp(obj.mesh.vertices[:, 2]))
    raised = float(mid[2] - hf.height_at(mid[0], mid[1])) - half_h
    return int(np.clip(np.floor(raised / half_h + 0.5), 0, 3))


def settle_dumps(scene_id: str, spawns, objects: dict[str, ObjectInfo], hf, physics: dict,
                 rng: np.random.Generator, bounds_xy, own=None) -> dict | None:
    """Pour the dumped piles (spawns with a fence, sonardet.sim.layout) into their ring fences and let
    them come to rest (MuJoCo, the `scenes.physics` settings, twice the time limit); the spawns of
    those elements are updated in place to their resting poses, from which the scene's
    settling (without the fences) lets each pile slump. Returns None when the scene has no dumped
    pile, else {spawn index: reason} for the elements the physics removed here (logged)."""
    dumped = [k for k, s in enumerate(spawns) if s.fence is not None]
    if not dumped:
        return None
    walls = [b for i, f in enumerate(_fences(spawns)) for b in _fence_bodies(f, float(hf.height_at(f.x, f.y)), str(i))]
    res = _settle(_bodies(spawns, dumped, objects, own) + walls, hf, physics, rng, bounds_xy,
                  2 * physics["max_time_s"])
    for i, name in enumerate(res.names):
        if name.startswith("o"):
            sp = spawns[int(name[1:])]
            sp.t, sp.q = np.asarray(res.pos[i], dtype=np.float64), np.asarray(res.quat[i], dtype=np.float64)
    gone = {int(rb.name[1:]): rb.reason for rb in res.removed if rb.name.startswith("o")}
    for k, reason in sorted(gone.items()):
        log.warning("%s: removed o%d (%s) while pouring its dumped pile: %s", scene_id, k, spawns[k].cls, reason)
    return gone


def settle_spawns(scene_id: str, spawns, objects: dict[str, ObjectInfo], hf, physics: dict,
                  rng: np.random.Generator, bounds_xy, static_bodies=(), own=None, skip: dict | None = None):
    """Drop the planned objects (bodies ``o{k}`` for spawn k) with MuJoCo onto the heightfield and the
    static bodies, with the `scenes.physics` settings. skip: {spawn index: reason} of spawns already
    removed (a dumped pile's pouring, :func:`settle_dumps`): not simulated, reported removed. Returns
    (settle result or None when there is nothing to drop, kept [(spawn index, t (3,), q (4,))], removed
    [{cls, reason, arrangement}], physics summary). Objects the physics removes are logged, never
    dropped silently."""
    skip = skip or {}
    pre = [{"cls": spawns[k].cls, "reason": f"pouring: {r}", "arrangement": spawns[k].arrangement}
           for k, r in sorted(skip.items())]
    if len(skip) == len(spawns):
        return None, [], pre, {"n_steps": 0, "sim_time_s": 0.0, "all_at_rest": True}
    bodies = _bodies(spawns, [k for k in range(len(spawns)) if k not in skip], objects, own) + list(static_bodies)
    res = _settle(bodies, hf, physics, rng, bounds_xy, physics["max_time_s"])
    removed = pre
    for rb in res.removed:
        if not rb.name.startswith("o"):
            continue
        k = int(rb.name[1:])
        removed.append({"cls": spawns[k].cls, "reason": rb.reason, "arrangement": spawns[k].arrangement})
        log.warning("%s: removed %s (%s) during settling: %s", scene_id, rb.name, spawns[k].cls, rb.reason)
    kept = [(int(n[1:]), res.pos[i], res.quat[i]) for i, n in enumerate(res.names) if n.startswith("o")]
    phys = {"n_steps": res.n_steps, "sim_time_s": res.sim_time_s, "all_at_rest": res.all_at_rest}
    return res, kept, removed, phys


def bury_objects(kept, spawns, burial_m, rng: np.random.Generator):
    """Sink settled objects into the sediment by a depth drawn per arrangement group from burial_m
    [min, max] (m): the burial effect (:mod:`sonardet.sim.effects.burial`) on the spawns' groups.
    Returns (kept with lowered t, depths (K,) or None when burial is off)."""
    return bury_settled(kept, [spawns[k].group for k, _, _ in kept], burial_m, rng)


def annotate_objects(kept, spawns, objects: dict[str, ObjectInfo], label: np.ndarray, min_points_visible: int,
                     buried=None, own=None) -> list[dict]:
    """The scene JSON's object entries (DESIGN.md section 3): id, class, pose, canonical box (of the
    object's own mesh in a mismatch scene), number of soundings (from `label`, object index per
    sounding or -1), visibility, arrangement, burial depth, the perturbation drawn (mismatch)."""
    n_pts = np.bincount(label[label >= 0], minlength=len(kept))
    objs = []
    for idx, (k, t, q) in enumerate(kept):
        sp = spawns[k]
        obj = _geometry(k, spawns, objects, own)
        box = canonical_box(obj.mesh.vertices, t, q, obj.symmetry_order)
        objs.append({
            "id": idx, "cls": sp.cls,
            "pose": {"t": [float(v) for v in t], "q": [float(v) for v in q]},
            "box": [float(v) for v in box],
            "n_points": int(n_pts[idx]),
            "visible": bool(n_pts[idx] >= min_points_visible),
            "arrangement": sp.arrangement, "group": int(sp.group), "layer": int(sp.layer),
            "dumped": sp.fence is not None,
        })
        if buried is not None:
            objs[-1]["burial_m"] = float(buried[idx])
        if own is not None:
            objs[-1]["perturbation"] = own[k][1]
    return objs
