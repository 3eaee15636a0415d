"""Procedural seabed: a sloping plane plus fractal gradient-noise relief, as a regular heightfield.

Frames and units: scene frame (x east, y north, z up), metres; slope angles in degrees where the name
says `_deg`. Azimuths are compass bearings (degrees clockwise from north, i.e. from +y towards +x);
`slope_azimuth_deg` is the direction the seabed dips *towards* (downhill), as hydrographers quote it
("a 2 deg slope dipping towards azimuth 135, SE").

Relief model. Perlin gradient noise (a random unit gradient at every lattice node, quintic fade,
bilinear blend of the four corner dot products) summed over octaves as fractal Brownian motion:
octave k has wavelength ``base_wavelength_m / 2**k`` and weight ``persistence**k``. A second,
fine-scale fBm adds centimetre roughness. Each octave's gradient lattice is drawn from the caller's
numpy Generator, so the same seed gives byte-identical grids.

Why hand-written and not a library (PyPI checked for this project): ``noise`` (Perlin/simplex, last
release 1.2.2 in 2015) ships only a C-extension source distribution, no wheels, so it needs a compiler
and is unmaintained; ``pyfastnoisesimd`` has no wheel for Python 3.11; ``opensimplex`` (0.4.5) is
pure Python with per-point loops that are fast only with numba (not a dependency here) and takes an
integer seed rather than a Generator; ``vnoise`` (vectorised Perlin, 2021) is unmaintained;
``pyfastnoiselite`` (a young Cython wrapper) has a cp311 wheel but adds a compiled dependency and its
own seeding for what is ~30 lines of vectorised numpy. The noise here is evaluated on a whole grid
at once (a default 44 x 44 m seabed at 0.1 m, 7 octaves in all: about 0.05-0.15 s on one core).

The :class:`Heightfield` is the seabed's single representation: bilinear heights and normals for
placement, a triangle mesh for ray casting (triangulated exactly as MuJoCo triangulates an ``hfield``
geom, so the sonar and the physics see the same surface), and cropping to a swath.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

#: Standard deviation of single-octave 2-D Perlin gradient noise with uniformly random unit gradients
#: (measured over 2e6 samples on a 400 x 400 lattice; used to give the relief a known RMS).
PERLIN_STD_2D = 0.2156


@dataclass(frozen=True, eq=False)
class Heightfield:
    """A seabed elevation grid in the scene frame.

    Node (j, i) lies at ``(x0 + i * cell_m, y0 + j * cell_m)`` with elevation ``z[j, i]`` (m, z up);
    `z` has shape (ny, nx), rows along y (south to north), columns along x (west to east), float64.
    Immutable by convention (compare grids with ``np.array_equal(a.z, b.z)``).
    """

    x0: float
    y0: float
    cell_m: float
    z: np.ndarray

    def __post_init__(self):
        z = np.asarray(self.z, dtype=np.float64)
        if z.ndim != 2 or z.shape[0] < 2 or z.shape[1] < 2:
            raise ValueError(f"Heightfield.z must be a 2-D grid of at least 2 x 2 nodes, got shape {z.shape}")
        if not np.all(np.isfinite(z)):
            raise ValueError("Heightfield.z holds NaN or Inf values")
        if not (np.isfinite(self.cell_m) and self.cell_m > 0):
            raise ValueError(f"Heightfield.cell_m must be > 0, got {self.cell_m}")
        object.__setattr__(self, "z", z)
        object.__setattr__(self, "x0", float(self.x0))
        object.__setattr__(self, "y0", float(self.y0))
        object.__setattr__(self, "cell_m", float(self.cell_m))

    # ------------------------------------------------------------------ geometry of the grid
    @property
    def ny(self) -> int:
        """Number of grid rows (nodes along y)."""
        return self.z.shape[0]

    @property
    def nx(self) -> int:
        """Number of grid columns (nodes along x)."""
        return self.z.shape[1]

    @property
    def x1(self) -> float:
        """x of the last grid column (m)."""
        return self.x0 + (self.nx - 1) * self.cell_m

    @property
    def y1(self) -> float:
        """y of the last grid row (m)."""
        return self.y0 + (self.ny - 1) * self.cell_m

    @property
    def extent_xy(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the grid (m), the convention of ``sim.mbes.survey_lines``."""
        return (self.x0, self.x1, self.y0, self.y1)

    @property
    def xs(self) -> np.ndarray:
        """x of the grid columns (nx,) (m)."""
        return self.x0 + np.arange(self.nx) * self.cell_m

    @property
    def ys(self) -> np.ndarray:
        """y of the grid rows (ny,) (m)."""
        return self.y0 + np.arange(self.ny) * self.cell_m

    def contains(self, x, y, margin_m: float = 0.0) -> np.ndarray:
        """Boolean mask: points (x, y) (m, broadcastable) at least margin_m inside the grid's extent."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return ((x >= self.x0 + margin_m) & (x <= self.x1 - margin_m)
                & (y >= self.y0 + margin_m) & (y <= self.y1 - margin_m))

    # ------------------------------------------------------------------ sampling
    def _cell_coords(self, x, y):
        """Cell indices and fractional offsets of points, plus the inside mask (NaN-safe)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        x, y = np.broadcast_arrays(x, y)
        tol = 1e-9 * self.cell_m
        inside = ((x >= self.x0 - tol) & (x <= self.x1 + tol) & (y >= self.y0 - tol) & (y <= self.y1 + tol))
        u = np.clip((np.where(inside, x, self.x0) - self.x0) / self.cell_m, 0.0, self.nx - 1)
        v = np.clip((np.where(inside, y, self.y0) - self.y0) / self.cell_m, 0.0, self.ny - 1)
        i = np.minimum(np.floor(u).astype(np.intp), self.nx - 2)
        j = np.minimum(np.floor(v).astype(np.intp), self.ny - 2)
        return i, j, u - i, v - j, inside

    def height_at(self, x, y) -> np.ndarray:
        """Seabed elevation z (m) at scene points (x, y) (m, broadcastable arrays) by bilinear interpolation.

        Points outside the grid's extent give NaN (never silently extrapolated). Returns float64 with
        the broadcast shape of x and y.
        """
        i, j, fu, fv, inside = self._cell_coords(x, y)
        z = self.z
        h = ((z[j, i] * (1 - fu) + z[j, i + 1] * fu) * (1 - fv)
             + (z[j + 1, i] * (1 - fu) + z[j + 1, i + 1] * fu) * fv)
        return np.where(inside, h, np.nan)

    def normal_at(self, x, y) -> np.ndarray:
        """Upward unit normals (..., 3) of the bilinear seabed surface at (x, y) (m); NaN outside the grid."""
        i, j, fu, fv, inside = self._cell_coords(x, y)
        z = self.z
        dzdx = ((z[j, i + 1] - z[j, i]) * (1 - fv) + (z[j + 1, i + 1] - z[j + 1, i]) * fv) / self.cell_m
        dzdy = ((z[j + 1, i] - z[j, i]) * (1 - fu) + (z[j + 1, i + 1] - z[j, i + 1]) * fu) / self.cell_m
        n = np.stack([-dzdx, -dzdy, np.ones_like(dzdx)], axis=-1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        return np.where(inside[..., None], n, np.nan)

    # ------------------------------------------------------------------ conversions
    def vertices(self) -> np.ndarray:
        """Grid nodes as (ny * nx, 3) float64 scene points, row-major (index j * nx + i)."""
        X, Y = np.meshgrid(self.xs, self.ys)
        return np.column_stack([X.ravel(), Y.ravel(), self.z.ravel()])

    def faces(self) -> np.ndarray:
        """Triangles (2 (ny-1)(nx-1), 3) int64 over the grid, counter-clockwise seen from above.

        Each cell is split along its (i, j)-(i+1, j+1) diagonal, as MuJoCo splits the prisms of an
        ``hfield`` geom, so the ray-cast surface and the physics surface are identical.
        """
        nx, ny = self.nx, self.ny
        jj, ii = np.meshgrid(np.arange(ny - 1), np.arange(nx - 1), indexing="ij")
        a = (jj * nx + ii).ravel()  # (i, j)
        b = a + 1                   # (i+1, j)
        c = a + nx + 1              # (i+1, j+1)
        d = a + nx                  # (i, j+1)
        f = np.empty((2 * a.size, 3), dtype=np.int64)
        f[0::2] = np.column_stack([a, b, c])
        f[1::2] = np.column_stack([a, c, d])
        return f

    def to_trimesh(self) -> trimesh.Trimesh:
        """Triangle mesh of the seabed surface (float64 vertices, see :meth:`vertices` and :meth:`faces`).

        An open surface (not watertight) meant for ray casting; built with ``process=False`` so vertex
        j * nx + i is exactly grid node (i, j).
        """
        return trimesh.Trimesh(vertices=self.vertices(), faces=self.faces(), process=False)

    def crop(self, xmin: float, xmax: float, ymin: float, ymax: float) -> "Heightfield":
        """Sub-heightfield covering the rectangle [xmin, xmax] x [ymin, ymax] (m), clipped to the grid.

        The sub-grid is the smallest set of whole cells enclosing the rectangle (so it shares nodes, and
        heights, with this field exactly). Raises ValueError when the rectangle misses the grid.
        """
        if not (xmax > xmin and ymax > ymin):
            raise ValueError(f"crop rectangle must have xmax > xmin and ymax > ymin, got {(xmin, xmax, ymin, ymax)}")
        if xmax < self.x0 or xmin > self.x1 or ymax < self.y0 or ymin > self.y1:
            raise ValueError(f"crop rectangle {(xmin, xmax, ymin, ymax)} does not overlap the heightfield "
                             f"extent {self.extent_xy}")
        eps = 1e-9
        i0 = int(np.clip(np.floor((xmin - self.x0) / self.cell_m + eps), 0, self.nx - 2))
        i1 = int(np.clip(np.ceil((xmax - self.x0) / self.cell_m - eps), i0 + 1, self.nx - 1))
        j0 = int(np.clip(np.floor((ymin - self.y0) / self.cell_m + eps), 0, self.ny - 2))
        j1 = int(np.clip(np.ceil((ymax - self.y0) / self.cell_m - eps), j0 + 1, self.ny - 1))
        return Heightfield(self.x0 + i0 * self.cell_m, self.y0 + j0 * self.cell_m, self.cell_m,
                           self.z[j0:j1 + 1, i0:i1 + 1].copy())

    def resample(self, cell_m: float) -> "Heightfield":
        """Heightfield over (at most) the same extent with a different cell size (m), by bilinear sampling."""
        if not cell_m > 0:
            raise ValueError(f"cell_m must be > 0, got {cell_m}")
        nx = max(2, int(np.floor((self.x1 - self.x0) / cell_m + 1e-9)) + 1)
        ny = max(2, int(np.floor((self.y1 - self.y0) / cell_m + 1e-9)) + 1)
        xs = np.minimum(self.x0 + np.arange(nx) * cell_m, self.x1)
        ys = np.minimum(self.y0 + np.arange(ny) * cell_m, self.y1)
        X, Y = np.meshgrid(xs, ys)
        return Heightfield(self.x0, self.y0, cell_m, self.height_at(X, Y))


# ---------------------------------------------------------------------------------- noise
def _fade(t: np.ndarray) -> np.ndarray:
    """Perlin's quintic fade 6t^5 - 15t^4 + 10t^3 (C2 continuous at lattice lines)."""
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def perlin_grid(xs, ys, wavelength_m: float, rng: np.random.Generator) -> np.ndarray:
    """One octave of 2-D Perlin gradient noise on the grid xs (nx,) x ys (ny,) (m) -> (ny, nx).

    The lattice spacing is wavelength_m; the lattice has a random sub-cell offset and random unit
    gradients, both drawn from rng. Values are dimensionless, mean 0, std ~PERLIN_STD_2D, |n| < 0.71.
    """
    xs = np.asarray(xs, dtype=np.float64)
    ys = np.asarray(ys, dtype=np.float64)
    if not wavelength_m > 0:
        raise ValueError(f"wavelength_m must be > 0, got {wavelength_m}")
    off = rng.uniform(0.0, 1.0, 2)
    u = (xs - xs.min()) / wavelength_m + off[0]
    v = (ys - ys.min()) / wavelength_m + off[1]
    nu = int(np.floor(u.max())) + 2
    nv = int(np.floor(v.max())) + 2
    ang = rng.uniform(0.0, 2.0 * np.pi, (nv, nu))
    gx, gy = np.cos(ang), np.sin(ang)
    i = np.floor(u).astype(np.intp)
    j = np.floor(v).astype(np.intp)
    fu = (u - i)[None, :]
    fv = (v - j)[:, None]

    def corner(di: int, dj: int) -> np.ndarray:
        # separable gather (rows, then columns) is several times faster than 2-D fancy indexing
        cx = gx.take(j + dj, axis=0).take(i + di, axis=1)
        cy = gy.take(j + dj, axis=0).take(i + di, axis=1)
        return cx * (fu - di) + cy * (fv - dj)

    a, b = _fade(fu), _fade(fv)
    return ((corner(0, 0) * (1 - a) + corner(1, 0) * a) * (1 - b)
            + (corner(0, 1) * (1 - a) + corner(1, 1) * a) * b)


def fbm_grid(xs, ys, base_wavelength_m: float, octaves: int, persistence: float, rng: np.random.Generator,
             lacunarity: float = 2.0, min_wavelength_m: float = 0.0) -> np.ndarray:
    """Fractal Brownian motion of Perlin noise on the grid xs x ys (m), normalised to unit expected std.

    Octave k has wavelength base_wavelength_m / lacunarity**k and weight persistence**k; octaves with a
    wavelength below min_wavelength_m (e.g. two grid cells, where they would alias) are skipped, but
    their random draws are still made so the coarse octaves do not depend on the grid spacing.
    Returns (ny, nx) float64, dimensionless, expected standard deviation 1.
    """
    if octaves < 1:
        raise ValueError(f"octaves must be >= 1, got {octaves}")
    if not 0.0 < persistence <= 1.0:
        raise ValueError(f"persistence must be in (0, 1], got {persistence}")
    xs = np.asarray(xs, dtype=np.float64)
    ys = np.asarray(ys, dtype=np.float64)
    out = np.zeros((ys.size, xs.size))
    var = 0.0
    for k in range(octaves):
        lam = base_wavelength_m / lacunarity ** k
        # Each octave gets its own child stream so skipping one never shifts the others' draws.
        child = np.random.default_rng(rng.integers(0, 2**63 - 1))
        if lam < min_wavelength_m:
            continue
        w = persistence ** k
        out += w * perlin_grid(xs, ys, lam, child)
        var += w * w
    if var == 0.0:
        return out
    return out / (PERLIN_STD_2D * np.sqrt(var))


# ---------------------------------------------------------------------------------- seabed
def _plane_fit(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Least-squares plane z = a + b (x - mean x) + c (y - mean y); returns (a, b, c)."""
    A = np.column_stack([np.ones(x.size), x - x.mean(), y - y.mean()])
    coef, *_ = np.linalg.lstsq(A, z, rcond=None)
    return coef


def plane_slope(hf: Heightfield, extent_xy=None) -> tuple[float, float, float]:
    """Best-fit plane of a heightfield's nodes (inside extent_xy = (xmin, xmax, ymin, ymax) if given).

    Returns (mean elevation m, slope deg, dip azimuth deg clockwise from north in [0, 360)).
    """
    X, Y = np.meshgrid(hf.xs, hf.ys)
    m = np.ones(X.shape, bool) if extent_xy is None else hf.contains(X, Y) & (
        (X >= extent_xy[0]) & (X <= extent_xy[1]) & (Y >= extent_xy[2]) & (Y <= extent_xy[3]))
    a, b, c = _plane_fit(X[m], Y[m], hf.z[m])
    slope = np.degrees(np.arctan(np.hypot(b, c)))
    # downhill direction is -grad = (-b, -c); compass azimuth = atan2(east, north)
    az = np.degrees(np.arctan2(-b, -c)) % 360.0
    return float(hf.z[m].mean()), float(slope), float(az)


def make_seabed(extent_m=(40.0, 40.0), cell_m: float = 0.1, mean_depth_m: float = -11.5,
                slope_deg: float = 1.0, slope_azimuth_deg: float = 135.0, amplitude_m: float = 0.15,
                base_wavelength_m: float = 10.0, octaves: int = 4, persistence: float = 0.5,
                roughness_m: float = 0.01, roughness_wavelength_m: float = 1.0, margin_m: float = 2.0,
                origin_xy=(0.0, 0.0), *, rng: np.random.Generator) -> Heightfield:
    """Procedural seabed heightfield: sloping plane + fBm relief + fine roughness (all metres).

    The scene rectangle is [x0, x0 + extent_m[0]] x [y0, y0 + extent_m[1]] with (x0, y0) = origin_xy;
    the grid covers it plus margin_m on every side (so objects and outer beams at the edge still see
    seabed), with nodes every cell_m.

    - Plane: slope_deg, dipping towards compass azimuth slope_azimuth_deg (clockwise from north).
    - Relief: fBm (`octaves` octaves from base_wavelength_m down, weight persistence**k), scaled so its
      expected standard deviation is amplitude_m / 2, i.e. about 95 % of the seabed lies within
      +-amplitude_m of the plane (pits and mounds of ~amplitude_m, like the 0.15-0.25 m ones of the
      R2Sonic line in shared/data/real, whose residual sigma to its plane is 0.08 m).
    - Roughness: a 3-octave fBm from roughness_wavelength_m down (octaves shorter than 2 cells are
      skipped) with expected standard deviation roughness_m.

    Relief and roughness are detrended over the scene rectangle (their least-squares plane removed),
    so the best-fit plane of the nodes inside the rectangle has exactly mean_depth_m, slope_deg and
    slope_azimuth_deg. Deterministic: same arguments and rng state give identical arrays.
    """
    ex, ey = (float(v) for v in extent_m)
    if not (ex > 0 and ey > 0):
        raise ValueError(f"extent_m must be positive, got {extent_m}")
    if not cell_m > 0:
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    if margin_m < 0 or amplitude_m < 0 or roughness_m < 0:
        raise ValueError("margin_m, amplitude_m and roughness_m must be >= 0")
    if not 0.0 <= slope_deg < 45.0:
        raise ValueError(f"slope_deg must be in [0, 45), got {slope_deg}")
    ox, oy = (float(v) for v in origin_xy)
    nx = int(np.ceil((ex + 2 * margin_m) / cell_m - 1e-9)) + 1
    ny = int(np.ceil((ey + 2 * margin_m) / cell_m - 1e-9)) + 1
    x0, y0 = ox - margin_m, oy - margin_m
    xs = x0 + np.arange(nx) * cell_m
    ys = y0 + np.arange(ny) * cell_m
    X, Y = np.meshgrid(xs, ys)

    relief = np.zeros((ny, nx))
    if amplitude_m > 0:
        relief += 0.5 * amplitude_m * fbm_grid(xs, ys, base_wavelength_m, octaves, persistence, rng,
                                               min_wavelength_m=2 * cell_m)
    if roughness_m > 0:
        relief += roughness_m * fbm_grid(xs, ys, roughness_wavelength_m, 3, 0.5, rng,
                                         min_wavelength_m=2 * cell_m)
    tol = 1e-9 * cell_m
    inside = (X >= ox - tol) & (X <= ox + ex + tol) & (Y >= oy - tol) & (Y <= oy + ey + tol)
    a, b, c = _plane_fit(X[inside], Y[inside], relief[inside])
    xm, ym = X[inside].mean(), Y[inside].mean()
    relief -= a + b * (X - xm) + c * (Y - ym)

    az = np.radians(slope_azimuth_deg)
    dip = np.array([np.sin(az), np.cos(az)])  # unit vector (east, north) pointing downhill
    grad = np.tan(np.radians(slope_deg))
    plane = mean_depth_m - grad * ((X - xm) * dip[0] + (Y - ym) * dip[1])
    return Heightfield(x0, y0, cell_m, plane + relief)
