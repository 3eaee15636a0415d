"""Physics-based settling of objects on the seabed with MuJoCo.

Bodies (reef elements, rocks) are dropped under gravity onto the seabed heightfield and onto each other
until every one is at rest; bodies that leave the area, sink through the seabed or never come to rest
are removed and reported, never silently kept.

Frames and units: scene frame (x east, y north, z up), metres, kilograms, seconds, radians;
quaternions (w, x, y, z) rotate a body's canonical frame (base centre at the origin, z up) into the
scene frame. A body's pose is that of its canonical frame, which is also its MuJoCo body frame (the
free joint's qpos), so poses go in and come out unchanged in meaning.

The MuJoCo model (built with ``mujoco.MjSpec``):

- Seabed: one ``hfield`` geom. MuJoCo places an hfield of ``size = (rx, ry, ez, bz)`` and ``nrow x
  ncol`` normalised elevations ``e`` in [0, 1] (row 0 = lowest y) so that node (r, c) lies at
  ``geom_pos + (-rx + 2 rx c / (ncol-1), -ry + 2 ry r / (nrow-1), e[r, c] * ez)`` with a solid base
  down to ``geom_pos.z - bz``. With ``rx = (nx-1) cell / 2``, ``geom_pos = (x0 + rx, y0 + ry, zmin)``,
  ``ez = zmax - zmin`` and ``e = (z - zmin) / ez`` the hfield nodes are exactly the
  :class:`~sonardet.sim.seabed.Heightfield` nodes (tested by dropping boxes). MuJoCo splits each cell
  into two triangular prisms along the (c, r)-(c+1, r+1) diagonal, as ``Heightfield.faces`` does. Only
  the part of the heightfield under ``bounds_xy`` (plus a margin) is given to MuJoCo.
- Bodies: one free joint each and one ``mesh`` geom per convex part (MuJoCo uses the convex hull of a
  mesh geom's vertices for collisions); the geoms' density is mass / (sum of hull volumes), so the
  body has the requested mass and the inertia of its parts. Static bodies (``static=True``, e.g. rocks
  embedded in the seabed) are fixed to the world at their given pose and not simulated.
- Contact: sliding friction 0.7 (concrete on sand or gravel is about 0.6-0.8). Contacts with the
  seabed also carry torsional and rolling resistance (condim 6) of ``rolling_resistance`` (0.1, a
  rolling-resistance coefficient of a hard body on sand) times the body's bounding radius, capped at
  ``rolling_max_m`` (2 cm): a small rounded rock then stops on a gentle slope or in a dip instead of
  rolling or rocking to and fro for the whole time limit (seen with 0.02 x radius: a 0.23 m rock
  still rocking at 0.6 rad/s after 10 s), as sediment stops it. Rolling resistance can also hold a
  body balanced on an edge whose centre of mass is within that distance of the edge; uncapped (8 cm
  for a tetrapod) it held 4 of 20 dropped tetrapods on two legs, with the 2 cm cap none (one of
  the 20 stood on a single leg's flat end, a real if fragile equilibrium). Elliptic
  friction cones with impratio 10 (MuJoCo's advice against slip; pyramidal cones and impratio 1
  showed bodies creeping and vibrating in place for seconds), MuJoCo's default soft contacts (solref
  0.02 s, which needs dt <= 10 ms; resting overlap is about 1 mm or less). multiccd (several
  contacts per convex-convex pair; default since MuJoCo 3.8, switched on here for older versions)
  keeps faces resting on faces stable.
- Water: a rotational dashpot per body (``angular_damping_time_s`` = 1 s: free spin decays as
  exp(-t / 1 s)) stands in for drag; it adds no static torque, so it cannot hold a body in a false
  equilibrium. Measured on the benchmark scenes (seeds 1-6): 5-54 % fewer steps for the tetrapod
  scenes, 1-15 % more for the catalog scenes (reef elements lowered upright); every scene settled
  either way.
- Integration: ``implicitfast``, Newton solver, dt 4 ms, noslip off (an extra solver pass per step;
  with pyramidal cones it made whole scenes of tetrapods creep, with elliptic cones it is not needed).

Cost: collision detection against the hfield dominates (MuJoCo tests every prism under a geom's
bounding box). ``hfield_cell_m`` can give MuJoCo a coarser copy of the seabed (0.2 m: about 2x
faster collision, objects then rest up to ~1 cm off the fine surface the sonar sees); the default is
the seabed's own grid.

"Simulate only bodies not yet at rest": with ``sleep=True`` (default) MuJoCo's island sleeping
(``mjENBL_SLEEP``, MuJoCo >= 3.4; developed and tested with 4.0) takes islands of bodies whose
velocities stayed below ``sleep_tolerance`` for 10 steps out of the pipeline (no collision
detection, no dynamics) until something awake touches them. ``benchmarks/physics.py`` measures the
saving against ``sleep=False``: 2.4-7.5x less wall time on five 40 x 40 m scenes of 75-80 bodies.

A body is *at rest* when, over the last settle_window_s, its origin moved less than
``lin_vel_tol * settle_window_s`` and it turned less than ``ang_vel_tol * settle_window_s`` (mean
velocities below the tolerances) and its current speeds are below ``SPEED_FACTOR`` (5) times the
tolerances; net motion rather than instantaneous speed, because soft contacts let a resting body
vibrate in place at ~0.01 rad/s. The simulation stops when every remaining dynamic body is at rest,
or at max_time_s.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import mujoco
import numpy as np
from scipy.spatial import ConvexHull

from ..geometry import quat_normalize
from .seabed import Heightfield

#: Reasons a body can be removed by :func:`settle`.
REASON_OUT_OF_BOUNDS = "out_of_bounds"  # its centre of mass left bounds_xy (or the terrain)
REASON_BELOW_TERRAIN = "below_terrain"  # its centre of mass sank below the seabed
REASON_NOT_SETTLED = "not_settled"      # still moving at max_time_s
REASON_BAD_START = "bad_start"          # spawned outside bounds_xy or below the seabed

#: A body at rest may still vibrate in place (soft contacts); its instantaneous speeds need only stay
#: below this multiple of the tolerances, while its net motion over the window must stay below them.
SPEED_FACTOR = 5.0


@dataclass
class RigidBody:
    """A body to settle.

    name: unique name. convex_parts: list of (V, 3) float64 vertex arrays in the body's canonical frame
    (m; base centre at the origin, z up); the union of their convex hulls is the body's solid.
    mass_kg: total mass. pos (3,): initial position of the canonical frame (m, scene frame).
    quat (4,): initial orientation (w, x, y, z). static: fixed in place (not simulated, but others
    collide with it).
    """

    name: str
    convex_parts: list
    mass_kg: float
    pos: np.ndarray
    quat: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))
    static: bool = False

    def __post_init__(self):
        self.pos = np.asarray(self.pos, dtype=np.float64).reshape(3)
        self.quat = quat_normalize(np.asarray(self.quat, dtype=np.float64).reshape(4))
        parts = [np.asarray(p, dtype=np.float64) for p in self.convex_parts]
        if not parts:
            raise ValueError(f"body {self.name!r}: convex_parts is empty")
        for k, p in enumerate(parts):
            if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 4 or not np.all(np.isfinite(p)):
                raise ValueError(f"body {self.name!r}: convex part {k} must be a finite (V>=4, 3) array, "
                                 f"got shape {p.shape}")
        self.convex_parts = parts
        if not (np.isfinite(self.mass_kg) and self.mass_kg > 0):
            raise ValueError(f"body {self.name!r}: mass_kg must be > 0, got {self.mass_kg}")
        if not np.all(np.isfinite(self.pos)):
            raise ValueError(f"body {self.name!r}: pos must be finite, got {self.pos}")


@dataclass
class RemovedBody:
    """A body removed by :func:`settle`: its name, the reason (REASON_*), sim time (s) and last position (m)."""

    name: str
    reason: str
    time_s: float
    pos: np.ndarray


@dataclass
class SettleResult:
    """Outcome of :func:`settle`.

    names: kept bodies (input order, static ones included). pos (K, 3) m and quat (K, 4) (w, x, y, z):
    their final poses in the scene frame. settle_time_s (K,): sim time at which each began its final
    rest (0 for static bodies). removed: bodies dropped, with reasons. n_steps, sim_time_s: steps taken
    and simulated time. wall_time_s: time spent stepping (model building excluded); build_time_s: model
    compile time. all_at_rest: every dynamic body still in play at the end met the rest criterion
    (False when some were removed as not_settled). initial_penetration_m: deepest overlap (m) between
    geoms at the start (bodies spawned inside each other or the seabed get pushed apart violently;
    spawn them clear, e.g. with :func:`place_above`). final_penetration_m: deepest overlap (m) between
    kept bodies, or a body and the seabed, at the end (soft contacts rest a few mm deep).
    touching: sorted (name, name) pairs of kept bodies in contact with each other at the end (piles).
    """

    names: list
    pos: np.ndarray
    quat: np.ndarray
    settle_time_s: np.ndarray
    removed: list
    n_steps: int
    sim_time_s: float
    wall_time_s: float
    build_time_s: float
    all_at_rest: bool
    initial_penetration_m: float = 0.0
    final_penetration_m: float = 0.0
    touching: list = field(default_factory=list)

    def pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(pos (3,), quat (4,)) of a kept body; KeyError (naming the removal reason) otherwise."""
        try:
            k = self.names.index(name)
        except ValueError:
            why = [r.reason for r in self.removed if r.name == name]
            raise KeyError(f"body {name!r} is not in the result" + (f" (removed: {why[0]})" if why else "")) from None
        return self.pos[k].copy(), self.quat[k].copy()

    @property
    def removed_names(self) -> list:
        """Names of the removed bodies."""
        return [r.name for r in self.removed]


def _hull_volume(v: np.ndarray) -> float:
    """Volume (m^3) of the convex hull of points v (V, 3); 0 for flat or degenerate sets."""
    try:
        return float(ConvexHull(v).volume)
    except Exception:  # noqa: BLE001 - qhull raises for coplanar/degenerate input
        return 0.0


def _physics_heightfield(hf: Heightfield, bounds_xy, margin_m: float, cell_m: float | None) -> Heightfield:
    """The part of hf MuJoCo needs: bounds_xy grown by margin_m, optionally resampled to cell_m."""
    xmin, xmax, ymin, ymax = bounds_xy
    sub = hf.crop(max(xmin - margin_m, hf.x0), min(xmax + margin_m, hf.x1),
                  max(ymin - margin_m, hf.y0), min(ymax + margin_m, hf.y1))
    if cell_m is not None and abs(cell_m - sub.cell_m) > 1e-12:
        sub = sub.resample(cell_m)
    return sub


def build_model(bodies: list[RigidBody], hf: Heightfield, *, dt_s: float = 0.004, friction: float = 0.7,
                sleep: bool = True, sleep_tolerance: float = 1e-3, base_m: float = 1.0,
                solver: str = "newton", seabed_condim: int = 6, rolling_resistance: float = 0.1,
                rolling_max_m: float = 0.02,
                cone: str = "elliptic", noslip_iterations: int = 0,
                solref_timeconst_s: float = 0.02, impratio: float = 10.0,
                angular_damping_time_s: float | None = 1.0) -> tuple[mujoco.MjModel, dict]:
    """Compile the MuJoCo model of the seabed hf and the bodies (see the module docstring).

    Returns (model, info) where info maps 'body_ids' (MuJoCo body id per dynamic input body, -1 for
    static ones), 'geom_ids' (list of geom id arrays per input body), 'qpos_adr' and 'qvel_adr'
    (address of each dynamic body's free joint in qpos/qvel, -1 for static), 'hfield_geom'.
    dt_s: time step (s). friction: sliding friction coefficient. sleep, sleep_tolerance (m/s): MuJoCo
    island sleeping. base_m: thickness (m) of the solid base MuJoCo puts under the lowest seabed
    point. solver: 'newton', 'cg' or 'pgs'. seabed_condim: contact dimensionality with the seabed (3:
    sliding only, 4: + torsion, 6: + rolling). rolling_resistance (dimensionless) and rolling_max_m
    (m): torsional/rolling friction length = min(rolling_resistance * bounding radius,
    rolling_max_m). cone: 'elliptic' or 'pyramidal'. noslip_iterations: MuJoCo noslip passes.
    solref_timeconst_s: contact stiffness time constant (s, >= 2 dt). impratio: friction-to-normal
    impedance ratio (elliptic cones). angular_damping_time_s: rotational damping time constant (s) of
    every free body, None for none.
    """
    spec = mujoco.MjSpec()
    spec.modelname = "sonardet_settle"
    _set_options(spec.option, dt_s=dt_s, solver=solver, cone=cone, noslip_iterations=noslip_iterations,
                 impratio=impratio, sleep=sleep, sleep_tolerance=sleep_tolerance)
    _add_seabed(spec, hf, friction=friction, condim=seabed_condim, base_m=base_m,
                solref_timeconst_s=solref_timeconst_s)
    geom_names = _add_bodies(spec, bodies, friction=friction, rolling_resistance=rolling_resistance,
                             rolling_max_m=rolling_max_m, solref_timeconst_s=solref_timeconst_s)
    model = spec.compile()
    return model, _model_info(model, bodies, geom_names, angular_damping_time_s)


def _set_options(opt, *, dt_s: float, solver: str, cone: str, noslip_iterations: int, impratio: float,
                 sleep: bool, sleep_tolerance: float) -> None:
    """MuJoCo options of the settling model (see :func:`build_model` for the arguments)."""
    opt.timestep = float(dt_s)
    opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    opt.solver = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG,
                  "pgs": mujoco.mjtSolver.mjSOL_PGS}[solver]
    opt.cone = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}[cone]
    opt.gravity = [0.0, 0.0, -9.81]
    opt.noslip_iterations = int(noslip_iterations)
    opt.impratio = float(impratio)

    if hasattr(mujoco.mjtEnableBit, "mjENBL_MULTICCD"):  # MuJoCo < 3.8: multiccd was opt-in
        opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_MULTICCD)
    if sleep:
        if not hasattr(mujoco.mjtEnableBit, "mjENBL_SLEEP"):
            raise RuntimeError(f"sleep=True needs MuJoCo >= 3.4 (island sleeping); this is MuJoCo "
                               f"{mujoco.__version__}: upgrade it or pass sleep=False")
        opt.sleep_tolerance = float(sleep_tolerance)
        opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)


def _add_seabed(spec, hf: Heightfield, *, friction: float, condim: int, base_m: float,
                solref_timeconst_s: float) -> None:
    """The seabed hfield geom whose nodes are exactly hf's (module docstring), base_m (m) of solid below."""
    z = hf.z
    zmin, zmax = float(z.min()), float(z.max())
    ez = max(zmax - zmin, 1e-6)
    rx = 0.5 * (hf.nx - 1) * hf.cell_m
    ry = 0.5 * (hf.ny - 1) * hf.cell_m
    hfield = spec.add_hfield(name="seabed", size=[rx, ry, ez, float(base_m)], nrow=hf.ny, ncol=hf.nx)
    hfield.userdata = ((z - zmin) / ez).astype(np.float32).ravel().tolist()
    spec.worldbody.add_geom(name="seabed", type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname="seabed",
                            pos=[hf.x0 + rx, hf.y0 + ry, zmin],
                            friction=[friction, 0.0, 0.0], condim=condim,
                            solref=[float(solref_timeconst_s), 1.0])


def _add_bodies(spec, bodies: list[RigidBody], *, friction: float, rolling_resistance: float,
                rolling_max_m: float, solref_timeconst_s: float) -> list[list[str]]:
    """One body b{i} per input body (a free joint unless static) with one mesh geom per convex part
    (shared meshes for equal parts), density mass / hull volume; returns the geom names per body."""
    mesh_names: dict[bytes, str] = {}
    hull_vol: dict[str, float] = {}
    for b in bodies:
        for p in b.convex_parts:
            key = p.tobytes()
            if key not in mesh_names:
                mname = f"hull{len(mesh_names)}"
                mesh_names[key] = mname
                spec.add_mesh(name=mname, uservert=p.astype(np.float64).ravel().tolist())
                hull_vol[mname] = _hull_volume(p)

    geom_names = []
    for bi, b in enumerate(bodies):
        parts = [mesh_names[p.tobytes()] for p in b.convex_parts]
        vol = sum(hull_vol[m] for m in parts)
        if vol <= 0:
            raise ValueError(f"body {b.name!r}: its convex parts have zero volume")
        density = b.mass_kg / vol
        # rolling / torsional resistance on the seabed (lengths, m) scale with the body's size:
        # coefficient rolling_resistance times its bounding radius (MuJoCo takes the larger of the two
        # geoms' values, and the seabed's are 0)
        radius = float(np.max(np.linalg.norm(np.vstack(b.convex_parts) - np.vstack(b.convex_parts).mean(0), axis=1)))
        roll = min(rolling_resistance * radius, rolling_max_m)
        body = spec.worldbody.add_body(name=f"b{bi}", pos=b.pos.tolist(), quat=b.quat.tolist())
        if not b.static:
            body.add_freejoint()
        names = []
        for k, mname in enumerate(parts):
            gname = f"b{bi}_g{k}"
            body.add_geom(name=gname, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mname, density=density,
                          friction=[friction, roll, roll], condim=3,
                          solref=[float(solref_timeconst_s), 1.0])
            names.append(gname)
        geom_names.append(names)
    return geom_names


def _model_info(model: mujoco.MjModel, bodies: list[RigidBody], geom_names: list[list[str]],
                angular_damping_time_s: float | None) -> dict:
    """The ids and addresses :func:`build_model` returns; sets each free body's angular damping."""
    info = {"body_ids": [], "geom_ids": [], "qpos_adr": [], "qvel_adr": [],
            "hfield_geom": mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "seabed")}
    for bi, b in enumerate(bodies):
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"b{bi}")
        info["geom_ids"].append(np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, g)
                                          for g in geom_names[bi]], dtype=np.int64))
        if b.static:
            info["body_ids"].append(-1)
            info["qpos_adr"].append(-1)
            info["qvel_adr"].append(-1)
        else:
            jid = model.body_jntadr[bid]
            info["body_ids"].append(bid)
            info["qpos_adr"].append(int(model.jnt_qposadr[jid]))
            info["qvel_adr"].append(int(model.jnt_dofadr[jid]))
            if angular_damping_time_s:
                # rotational dashpot (water drag, sediment): free angular velocity decays as
                # exp(-t / angular_damping_time_s); damping creates no static torque, so unlike rolling
                # friction it cannot hold a body in a false equilibrium
                a = int(model.jnt_dofadr[jid])
                model.dof_damping[a + 3:a + 6] = float(np.mean(model.body_inertia[bid])) / angular_damping_time_s
    return info


def settle(bodies: list[RigidBody], heightfield: Heightfield, *, rng: np.random.Generator,
           max_time_s: float = 10.0, dt_s: float = 0.004, lin_vel_tol: float = 0.01,
           ang_vel_tol: float = 0.02, settle_window_s: float = 0.3, bounds_xy=None,
           friction: float = 0.7, sleep: bool = True, sleep_tolerance: float = 1e-3,
           below_terrain_m: float = 0.2, perturb_ang_vel_rad_s: float = 0.02,
           hfield_cell_m: float | None = None, hfield_margin_m: float = 2.0,
           solver: str = "newton", **model_options) -> SettleResult:
    """Drop the bodies under gravity onto the heightfield (and each other) until all are at rest.

    bodies: list of :class:`RigidBody` (unique names). heightfield: the seabed (scene frame, m).
    rng: draws a small random initial angular velocity per dynamic body (magnitude
    perturb_ang_vel_rad_s, rad/s) that breaks exact balance on an edge or a tip; same rng state, same
    inputs -> identical result. dt_s: time step (s). max_time_s: simulated-time limit (s).
    lin_vel_tol (m/s), ang_vel_tol (rad/s), settle_window_s (s): the rest criterion (module docstring).
    bounds_xy: (xmin, xmax, ymin, ymax) (m) a body's centre of mass must stay in; default: the
    heightfield's extent. friction: sliding friction coefficient (bodies and seabed).
    sleep: use MuJoCo's island sleeping for bodies at rest (False = simulate everything every step;
    same rest criterion). sleep_tolerance: MuJoCo's sleep velocity threshold (m/s).
    below_terrain_m: a body whose centre of mass is more than this (m) below the seabed under it has
    fallen through and is removed. hfield_cell_m: give MuJoCo the seabed resampled to this cell size
    (None: the seabed's own grid). hfield_margin_m: seabed kept around bounds_xy (m). solver: 'newton',
    'cg' or 'pgs'. model_options: passed to :func:`build_model` (e.g. cone, impratio,
    rolling_resistance, seabed_condim, noslip_iterations, solref_timeconst_s, base_m).

    Static bodies are kept at their pose, never simulated and never removed. Dynamic bodies are
    removed (reasons REASON_*) when spawned with their centre of mass outside bounds_xy or more than
    below_terrain_m below the seabed (bad_start, never simulated), when their centre of mass leaves
    bounds_xy (out_of_bounds) or sinks below the seabed (below_terrain), both checked every ~50 ms,
    or when still moving at max_time_s (not_settled). A removed body stops colliding at once.
    """
    names = [b.name for b in bodies]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"body names must be unique; duplicated: {dup}")
    if not (dt_s > 0 and max_time_s > 0 and settle_window_s >= 0):
        raise ValueError("dt_s and max_time_s must be > 0 and settle_window_s >= 0")
    if bounds_xy is None:
        bounds_xy = heightfield.extent_xy
    xmin, xmax, ymin, ymax = (float(v) for v in bounds_xy)
    if not (xmax > xmin and ymax > ymin):
        raise ValueError(f"bounds_xy must be (xmin, xmax, ymin, ymax) with max > min, got {bounds_xy}")
    bounds = (xmin, xmax, ymin, ymax)
    keep, removed = _reject_bad_starts(bodies, heightfield, bounds, below_terrain_m)

    t_build = time.perf_counter()
    phys_hf = _physics_heightfield(heightfield, bounds, hfield_margin_m, hfield_cell_m)
    model, info = build_model(keep, phys_hf, dt_s=dt_s, friction=friction, sleep=sleep,
                              sleep_tolerance=sleep_tolerance, solver=solver,
                              **model_options)
    data = mujoco.MjData(model)
    build_time = time.perf_counter() - t_build

    run = _Settling(model, data, info, keep, heightfield, bounds, dt_s=dt_s, settle_window_s=settle_window_s,
                    lin_vel_tol=lin_vel_tol, ang_vel_tol=ang_vel_tol, below_terrain_m=below_terrain_m)
    run.perturb(rng, perturb_ang_vel_rad_s)
    init_pen = float(max(0.0, -data.contact.dist[:data.ncon].min())) if data.ncon else 0.0
    t0 = time.perf_counter()
    steps = run.run(int(np.ceil(max_time_s / dt_s)))
    wall = time.perf_counter() - t0
    all_at_rest = bool(np.all(run.rest[run.active]))
    for k in np.flatnonzero(run.active & ~run.rest):
        run.remove(int(k), REASON_NOT_SETTLED)
    final_pen, touching = _final_contacts(model, data, info, keep, sleep)
    result = run.result(names, removed)
    return SettleResult(
        **result, n_steps=steps, sim_time_s=float(data.time), wall_time_s=wall, build_time_s=build_time,
        all_at_rest=all_at_rest, initial_penetration_m=init_pen, final_penetration_m=final_pen, touching=touching,
    )


def _reject_bad_starts(bodies: list[RigidBody], heightfield: Heightfield, bounds, below_terrain_m: float):
    """Dynamic bodies spawned with their centre of mass outside bounds (xmin, xmax, ymin, ymax) or
    more than below_terrain_m (m) below the seabed are removed before the model is built (so they
    cannot disturb others); static bodies are never simulated and always kept. Returns (kept bodies,
    removed [RemovedBody])."""
    xmin, xmax, ymin, ymax = bounds
    removed: list[RemovedBody] = []
    keep = []
    for b in bodies:
        if b.static:
            keep.append(b)
            continue
        c = b.pos + _rot(b.quat) @ np.vstack(b.convex_parts).mean(0)  # approximate centre of mass
        h = float(heightfield.height_at(c[0], c[1])) if heightfield.contains(c[0], c[1]) else np.nan
        if not (xmin <= c[0] <= xmax and ymin <= c[1] <= ymax) or np.isnan(h) or c[2] < h - below_terrain_m:
            removed.append(RemovedBody(b.name, REASON_BAD_START, 0.0, c))
            continue
        keep.append(b)
    return keep, removed


def _final_contacts(model: mujoco.MjModel, data: mujoco.MjData, info: dict, keep: list[RigidBody], sleep: bool):
    """(deepest remaining overlap (m) among kept bodies and the seabed, sorted (name, name) pairs of
    kept bodies in contact). Sleeping islands skip their own contacts, so everything is woken (the
    sleep flag cleared) and the contacts recomputed once."""
    if sleep:
        model.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    mujoco.mj_forward(model, data)
    final_pen = float(max(0.0, -data.contact.dist[:data.ncon].min())) if data.ncon else 0.0
    geom_owner = np.full(model.ngeom, -1, np.int64)
    for kk, g in enumerate(info["geom_ids"]):
        geom_owner[g] = kk
    pairs = set()
    for c in range(data.ncon):
        a_, b_ = geom_owner[data.contact.geom1[c]], geom_owner[data.contact.geom2[c]]
        if a_ >= 0 and b_ >= 0 and a_ != b_:
            pairs.add((min(a_, b_), max(a_, b_)))
    return final_pen, sorted((keep[a_].name, keep[b_].name) for a_, b_ in pairs)


class _Settling:
    """The stepping of :func:`settle`: the dynamic bodies' state (active, at rest, rest start), the
    rest criterion over a sliding window of poses, the bounds and sinking checks, removals."""

    def __init__(self, model, data, info: dict, keep: list[RigidBody], heightfield: Heightfield, bounds, *,
                 dt_s: float, settle_window_s: float, lin_vel_tol: float, ang_vel_tol: float,
                 below_terrain_m: float):
        self.model, self.data, self.info, self.keep, self.hf = model, data, info, keep, heightfield
        self.bounds, self.dt_s, self.below_terrain_m = bounds, dt_s, below_terrain_m
        self.lin_vel_tol, self.ang_vel_tol = lin_vel_tol, ang_vel_tol
        self.dyn = dyn = np.array([k for k, b in enumerate(keep) if not b.static], dtype=np.int64)
        self.qvel_adr = np.array([info["qvel_adr"][k] for k in dyn], dtype=np.int64)
        self.qpos_adr = qpos_adr = np.array([info["qpos_adr"][k] for k in dyn], dtype=np.int64)
        self.body_ids = np.array([info["body_ids"][k] for k in dyn], dtype=np.int64)
        self.n = n = dyn.size
        self.active = np.ones(n, bool)           # not removed
        self.rest = np.zeros(n, bool)            # rest criterion met at the current step
        self.rest_since = np.full(n, np.nan)     # start of the current rest period (sim time, s)
        self.lin_idx = self.qvel_adr[:, None] + np.arange(3)[None, :]
        self.ang_idx = self.lin_idx + 3
        self.pos_idx = qpos_adr[:, None] + np.arange(3)[None, :]
        self.quat_idx = qpos_adr[:, None] + np.arange(3, 7)[None, :]
        self.window = window = max(1, int(round(settle_window_s / dt_s)))
        self.max_disp = lin_vel_tol * window * dt_s      # allowed net motion over the window (m)
        self.max_turn = ang_vel_tol * window * dt_s      # allowed net rotation over the window (rad)
        self.hist_pos = np.empty((window, n, 3))         # ring buffer of poses over the last window
        self.hist_quat = np.empty((window, n, 4))
        self.check_every = max(1, int(round(0.05 / dt_s)))  # bounds / sinking checks every ~50 ms
        self.removed_dyn = {}

    def perturb(self, rng: np.random.Generator, ang_vel_rad_s: float) -> None:
        """A small random spin (body frame, rad/s) per dynamic body, drawn in input order (it breaks
        exact balance); then the forward pass of the start."""
        for a in self.qvel_adr:
            w = rng.normal(size=3)
            w *= ang_vel_rad_s / max(np.linalg.norm(w), 1e-12)
            self.data.qvel[a + 3:a + 6] = w
        mujoco.mj_forward(self.model, self.data)

    def remove(self, k: int, reason: str) -> None:
        """Take dynamic body k out of play (it stops colliding at once) for `reason`."""
        self.active[k] = False
        g = self.info["geom_ids"][self.dyn[k]]
        self.model.geom_contype[g] = 0
        self.model.geom_conaffinity[g] = 0
        self.removed_dyn[k] = RemovedBody(self.keep[self.dyn[k]].name, reason, float(self.data.time),
                                          self.data.xipos[self.body_ids[k]].copy())

    def run(self, max_steps: int) -> int:
        """Step until every active body is at rest or max_steps; returns the steps taken."""
        data, window = self.data, self.window
        steps = 0
        while steps < max_steps and self.n and self.active.any():
            slot = steps % window
            self.hist_pos[slot] = data.qpos[self.pos_idx]
            self.hist_quat[slot] = data.qpos[self.quat_idx]
            mujoco.mj_step(self.model, data)
            steps += 1
            if steps >= window:
                self._update_rest((slot + 1) % window)  # the pose `window` steps before now
            if steps % self.check_every == 0:
                self._check_bounds()
            if np.all(self.rest[self.active]):
                break
        return steps

    def _update_rest(self, old: int) -> None:
        """The rest criterion against the poses of ring-buffer slot `old` (module docstring)."""
        data, dt_s, window = self.data, self.dt_s, self.window
        disp = np.linalg.norm(data.qpos[self.pos_idx] - self.hist_pos[old], axis=1)
        dot = np.abs(np.einsum("ij,ij->i", data.qpos[self.quat_idx], self.hist_quat[old]))
        turn = 2.0 * np.arccos(np.minimum(dot / np.linalg.norm(data.qpos[self.quat_idx], axis=1)
                                          / np.linalg.norm(self.hist_quat[old], axis=1), 1.0))
        v = data.qvel
        lin = np.linalg.norm(v[self.lin_idx], axis=1)
        ang = np.linalg.norm(v[self.ang_idx], axis=1)
        now = ((disp < self.max_disp) & (turn < self.max_turn)
               & (lin < SPEED_FACTOR * self.lin_vel_tol) & (ang < SPEED_FACTOR * self.ang_vel_tol))
        self.rest_since[now & ~self.rest] = data.time - window * dt_s
        self.rest = now

    def _check_bounds(self) -> None:
        """Remove bodies whose centre of mass left the bounds or sank below the seabed."""
        xmin, xmax, ymin, ymax = self.bounds
        com = self.data.xipos[self.body_ids]
        h = self.hf.height_at(com[:, 0], com[:, 1])
        out = ((com[:, 0] < xmin) | (com[:, 0] > xmax) | (com[:, 1] < ymin) | (com[:, 1] > ymax)
               | np.isnan(h))
        for k in np.flatnonzero(out & self.active):
            self.remove(int(k), REASON_OUT_OF_BOUNDS)
        sunk = ~out & (com[:, 2] < h - self.below_terrain_m)
        for k in np.flatnonzero(sunk & self.active):
            self.remove(int(k), REASON_BELOW_TERRAIN)

    def result(self, names: list[str], removed: list[RemovedBody]) -> dict:
        """Kept bodies' names, poses and settle times in input order, and every removal in input
        order (the SettleResult fields names, pos, quat, settle_time_s, removed)."""
        data = self.data
        dyn_pos = {int(d): j for j, d in enumerate(self.dyn)}
        out_names, out_pos, out_quat, out_t = [], [], [], []
        removed_by_name = {r.name: r for r in removed}
        for r in self.removed_dyn.values():
            removed_by_name[r.name] = r
        for kk, b in enumerate(self.keep):
            if b.name in removed_by_name:
                continue
            out_names.append(b.name)
            if b.static:
                out_pos.append(b.pos.copy())
                out_quat.append(b.quat.copy())
                out_t.append(0.0)
            else:
                j = dyn_pos[kk]
                qp = data.qpos[self.qpos_adr[j]:self.qpos_adr[j] + 7]
                out_pos.append(qp[:3].copy())
                out_quat.append(quat_normalize(qp[3:7].copy()))
                out_t.append(float(self.rest_since[j]))
        return {"names": out_names, "pos": np.array(out_pos, dtype=np.float64).reshape(-1, 3),
                "quat": np.array(out_quat, dtype=np.float64).reshape(-1, 4),
                "settle_time_s": np.array(out_t, dtype=np.float64),
                "removed": [removed_by_name[nm] for nm in names if nm in removed_by_name]}


def place_above(convex_parts, quat, xy, heightfield: Heightfield, clearance_m: float = 0.05) -> np.ndarray:
    """Spawn position (3,) (m) putting a body's canonical origin above scene point xy so that its lowest
    point, in orientation quat (w, x, y, z), is clearance_m above the highest seabed node under its
    footprint (conservative: the body starts clear of the seabed anywhere under it)."""
    R = _rot(quat_normalize(np.asarray(quat, dtype=np.float64)))
    v = np.vstack([np.asarray(p, dtype=np.float64) for p in convex_parts]) @ R.T
    x, y = float(xy[0]), float(xy[1])
    lo = v[:, :2].min(0) + (x, y)
    hi = v[:, :2].max(0) + (x, y)
    if not (heightfield.contains(lo[0], lo[1]) and heightfield.contains(hi[0], hi[1])):
        raise ValueError(f"footprint {lo.tolist()}-{hi.tolist()} of a body at {(x, y)} is not inside the "
                         f"heightfield extent {heightfield.extent_xy}")
    top = float(heightfield.crop(lo[0], max(hi[0], lo[0] + 1e-6), lo[1], max(hi[1], lo[1] + 1e-6)).z.max())
    return np.array([x, y, top - float(v[:, 2].min()) + clearance_m])


def _rot(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
