"""Figures of single scenes: top view with boxes, 3D object poses, and a dataset example.

Everything is in the scene frame (metres, x east, y north, z up). Each function writes one PNG and
returns its path; they are re-exported by `sonardet.report.figures`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from ..geometry import box_corners, transform_points
from ..io.annotations import read_detections
from .inputs import read_json
from .style import GT_STYLE, HEIGHT_CMAP, class_color, method_style, new_figure, write_figure

# ---------------------------------------------------------------------------------------------------
# Inputs


def _points(scene_npz) -> dict:
    """Scene soundings from a `scenes/{scene}.npz` path, a loaded dict, or an (N,3) array."""
    if isinstance(scene_npz, dict):
        return scene_npz
    if isinstance(scene_npz, np.ndarray):
        return {"xyz": np.asarray(scene_npz, dtype=np.float64)}
    from ..io.scenes import read_scene_points

    return read_scene_points(scene_npz)


def detection_list(source) -> list[dict]:
    """Detections as a list of {cls, box, score, pose?}: from a detection file path, a detection
    document ({..., detections: [...]}) or the list itself."""
    if isinstance(source, (list, tuple)):
        return list(source)
    if isinstance(source, dict):
        return list(source["detections"])
    return read_detections(source, check_filename=False)["detections"]


def _subsample(n: int, max_points: int, seed: int) -> np.ndarray:
    if n <= max_points:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, size=max_points, replace=False))


def _height_limits(z: np.ndarray) -> tuple[float, float]:
    # Percentiles, so a few outlier soundings do not wash out the colour scale.
    lo, hi = np.percentile(z, [1.0, 99.5]) if len(z) else (0.0, 1.0)
    return float(lo), float(max(hi, lo + 1e-3))


def _dot_size(n: int) -> float:
    """Marker area (pt^2) for n soundings in a panel: small for dense clouds, visible for sparse ones."""
    return float(np.clip(2e4 / max(n, 1), 0.15, 4.0))


def _box_segments(boxes) -> list[np.ndarray]:
    """Closed xy outlines (5,2) of boxes [x,y,z,l,w,h,yaw]."""
    out = []
    for b in boxes:
        c = box_corners(b)[:4, :2]
        out.append(np.vstack([c, c[:1]]))
    return out


def _scene_limits(scene: dict, xyz: np.ndarray):
    ext = scene.get("extent")
    if isinstance(ext, (list, tuple)) and len(ext) == 4:
        return (ext[0], ext[1]), (ext[2], ext[3])
    if len(xyz):
        return (xyz[:, 0].min(), xyz[:, 0].max()), (xyz[:, 1].min(), xyz[:, 1].max())
    return (0.0, 1.0), (0.0, 1.0)


# ---------------------------------------------------------------------------------------------------
# Top view


def plot_topview(scene_npz, scene_json, detections: dict, out_png, max_points: int = 200_000,
                 seed: int = 0) -> Path:
    """Top view of a scene: soundings coloured by elevation z (m), ground-truth boxes (black, solid;
    hidden objects grey, dotted) and each method's boxes in its own colour and linestyle, one panel
    per method (ground truth in every panel).

    scene_npz: `scenes/{scene}.npz` path (or loaded dict / (N,3) array); scene_json: path or dict;
    detections: method -> detection file path, document or list. At most max_points soundings are
    drawn (random subset, fixed seed). Returns out_png.
    """
    xyz = _points(scene_npz)["xyz"]
    scene = read_json(scene_json)
    dets = {m: detection_list(d) for m, d in detections.items()}
    panels = list(dets) or [None]
    ncols = min(len(panels), 3)
    nrows = int(np.ceil(len(panels) / ncols))
    fig = new_figure(5.0 * ncols + 0.8, 4.9 * nrows)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    idx = _subsample(len(xyz), max_points, seed)
    p = xyz[idx][np.argsort(xyz[idx, 2], kind="stable")]  # high points drawn last
    vmin, vmax = _height_limits(p[:, 2])
    xlim, ylim = _scene_limits(scene, xyz)
    objs = scene.get("objects", [])
    gt_vis = _box_segments([o["box"] for o in objs if o.get("visible", True)])
    gt_hid = _box_segments([o["box"] for o in objs if not o.get("visible", True)])
    sc = None
    for ax, method in zip(axes, panels):
        sc = ax.scatter(p[:, 0], p[:, 1], c=p[:, 2], s=_dot_size(len(p)), cmap=HEIGHT_CMAP, vmin=vmin, vmax=vmax,
                        linewidths=0, rasterized=True)
        ax.add_collection(LineCollection(gt_vis, colors=GT_STYLE["color"], linewidths=1.1, linestyles="-"))
        if gt_hid:
            ax.add_collection(LineCollection(gt_hid, colors="#777777", linewidths=0.9, linestyles=":"))
        handles = [Line2D([], [], color=GT_STYLE["color"], ls="-", label=f"ground truth ({len(gt_vis)})")]
        if method is None:
            ax.set_title(f"scene {scene.get('scene', '')}: ground truth")
        else:
            st = method_style(method)
            ax.add_collection(LineCollection(_box_segments([d["box"] for d in dets[method]]), colors=st["color"],
                                             linewidths=1.3, linestyles=st["linestyle"]))
            handles.append(Line2D([], [], color=st["color"], ls=st["linestyle"], lw=1.3,
                                  label=f"{method} ({len(dets[method])})"))
            ax.set_title(f"scene {scene.get('scene', '')}: {method}")
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m, east)")
        ax.set_ylabel("y (m, north)")
        ax.legend(handles=handles, loc="upper right", fontsize=7, framealpha=0.85)
    for ax in axes[len(panels):]:
        ax.set_axis_off()
    fig.colorbar(sc, ax=list(axes[:len(panels)]), shrink=0.8, label="elevation z (m)")
    return write_figure(fig, out_png)


# ---------------------------------------------------------------------------------------------------
# 3D poses


def densest_region(centres_xy, size_m: float = 15.0) -> tuple[float, float, float, float]:
    """Square window (xmin, xmax, ymin, ymax) (m) of side size_m, centred on the object centre (N,2)
    with the most other centres inside such a window (first one on ties)."""
    c = np.asarray(centres_xy, dtype=np.float64).reshape(-1, 2)
    if len(c) == 0:
        raise ValueError("densest_region: no object centres given")
    half = 0.5 * float(size_m)
    inside = np.all(np.abs(c[:, None, :] - c[None, :, :]) <= half, axis=2)
    x, y = c[int(np.argmax(inside.sum(1)))]
    return (x - half, x + half, y - half, y + half)


def decimate_mesh(mesh, max_faces: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V,3), faces (F,3)) of a trimesh mesh with at most about max_faces faces, for drawing.

    Uses Open3D's quadric decimation (keeps holes and outline, e.g. of a ring); without Open3D the
    largest faces are kept.
    """
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    if len(f) <= max_faces:
        return v, f
    try:
        import open3d as o3d
    except ImportError:
        area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
        return v, f[np.sort(np.argsort(-area)[:max_faces])]
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32)))
    s = m.simplify_quadric_decimation(target_number_of_triangles=int(max_faces))
    return np.asarray(s.vertices), np.asarray(s.triangles, dtype=np.int64)


def place_mesh(vertices, item: dict) -> np.ndarray:
    """Scene-frame vertices (V,3) of a canonical mesh for a ground-truth object or a detection.

    With a pose {t, q (w,x,y,z)} the mesh is moved by it. Without one (the learned detector gives only
    a box) the mesh is rotated by the box yaw about z and translated so that the centre of its
    canonical bounding box coincides with the box centre, i.e. it sits upright in the box.
    """
    v = np.asarray(vertices, dtype=np.float64)
    pose = item.get("pose")
    if pose:
        return transform_points(v, pose["t"], pose["q"])
    b = np.asarray(item["box"], dtype=np.float64)
    c, s = np.cos(b[6]), np.sin(b[6])
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return (v - 0.5 * (v.min(0) + v.max(0))) @ rz.T + b[:3]


def _in_region(items, region) -> list[dict]:
    x0, x1, y0, y1 = region
    return [it for it in items if x0 <= it["box"][0] <= x1 and y0 <= it["box"][1] <= y1]


def _load_objects(objects: dict) -> dict:
    from ..objects import read_object

    return {c: (read_object(o) if isinstance(o, (str, Path)) else o) for c, o in objects.items()}


def plot_3d_poses(scene_json, detections: dict, objects: dict, out_png, region=None, scene_npz=None,
                  size_m: float = 15.0, max_faces: int = 200, max_points: int = 15_000,
                  min_score: float = 0.0, seed: int = 0) -> Path:
    """3D views of the object meshes at the ground-truth poses and at each method's detected poses
    (panels: ground truth, then one per method), meshes coloured by class.

    scene_json: path or dict; detections: method -> detection file path, document or list; objects:
    cls -> ObjectInfo (or its `objects/{cls}.json` path). Model-based detections carry a pose and are
    drawn with it; detections without a pose are placed upright in their box (see `place_mesh`).
    region: (xmin, xmax, ymin, ymax) in m; default the size_m x size_m window around the densest
    cluster of ground-truth objects. With scene_npz, up to max_points soundings of the region are
    drawn as grey dots. Meshes are decimated to about max_faces faces; detections scoring below
    min_score and objects of a class missing from `objects` are left out. Returns out_png.
    """
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    scene = read_json(scene_json)
    objs = _load_objects(objects)
    gt = [o for o in scene.get("objects", []) if o.get("visible", True)]
    if region is None and gt:
        region = densest_region([o["box"][:2] for o in gt], size_m)
    elif region is None:
        (x0, x1), (y0, y1) = _scene_limits(scene, np.zeros((0, 3)))
        region = (x0, x1, y0, y1)
    region = tuple(float(r) for r in region)
    meshes = {c: decimate_mesh(o.mesh, max_faces) for c, o in objs.items()}
    panels = [("ground truth", _in_region(gt, region))]
    for m, d in detections.items():
        panels.append((m, _in_region([x for x in detection_list(d) if x["score"] >= min_score], region)))

    pts = None
    if scene_npz is not None:
        xyz = _points(scene_npz)["xyz"]
        x0, x1, y0, y1 = region
        sel = xyz[(xyz[:, 0] >= x0) & (xyz[:, 0] <= x1) & (xyz[:, 1] >= y0) & (xyz[:, 1] <= y1)]
        pts = sel[_subsample(len(sel), max_points, seed)]
    zs = [o["box"][2] + s * 0.5 * o["box"][5] for o in panels[0][1] for s in (-1, 1)]
    if pts is not None and len(pts):
        zs += [float(pts[:, 2].min()), float(pts[:, 2].max())]
    zlo, zhi = (min(zs) - 0.2, max(zs) + 0.2) if zs else (-1.0, 1.0)

    fig = new_figure(4.6 * len(panels), 4.3)
    for k, (title, items) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), k + 1, projection="3d")
        if pts is not None and len(pts):
            ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=0.3, c="#9a9a9a", alpha=0.35, linewidths=0,
                       depthshade=False, rasterized=True)
        n = 0
        for it in items:
            if it["cls"] not in meshes:
                continue
            v, f = meshes[it["cls"]]
            pv = place_mesh(v, it)
            col = class_color(it["cls"])
            ax.add_collection3d(Poly3DCollection(pv[f], facecolors=col, edgecolors=col, linewidths=0.1,
                                                 alpha=0.9, shade=True))
            n += 1
        ax.set_xlim(region[0], region[1])
        ax.set_ylim(region[2], region[3])
        ax.set_zlim(zlo, zhi)
        dx, dy, dz = region[1] - region[0], region[3] - region[2], zhi - zlo
        ax.set_box_aspect((dx, dy, max(dz, 0.2 * max(dx, dy))))
        ax.view_init(elev=35, azim=-60)
        ax.set_xlabel("x (m)", fontsize=8)
        ax.set_ylabel("y (m)", fontsize=8)
        ax.set_zlabel("z (m)", fontsize=8)
        ax.tick_params(labelsize=6)
        what = "objects" if k == 0 else "detections"
        ax.set_title(f"{title} ({n} {what})", fontsize=10)
    present = sorted({it["cls"] for _, items in panels for it in items if it["cls"] in meshes})
    if present:
        fig.legend(handles=[Patch(color=class_color(c), label=c) for c in present], loc="lower center",
                   ncol=len(present), fontsize=8)
    fig.suptitle(f"scene {scene.get('scene', '')}: x {region[0]:.0f}-{region[1]:.0f} m, "
                 f"y {region[2]:.0f}-{region[3]:.0f} m")
    return write_figure(fig, out_png)


# ---------------------------------------------------------------------------------------------------
# Dataset example


def _line_tracks(pts: dict):
    """Per survey line: (line id, start xy, end xy), from the soundings of its first and last pings."""
    if "line" not in pts or "ping" not in pts:
        return []
    xyz, line, ping = pts["xyz"], np.asarray(pts["line"]), np.asarray(pts["ping"])
    out = []
    for ln in np.unique(line):
        m = line == ln
        pg = ping[m]
        first, last = pg.min(), pg.max()
        if first == last:
            continue
        a = xyz[m][pg == first][:, :2].mean(0)
        b = xyz[m][pg == last][:, :2].mean(0)
        out.append((int(ln), a, b))
    return out


def plot_dataset_example(scene_npz, scene_json, out_png, max_points: int = 200_000, seed: int = 0) -> Path:
    """A simulated scene as in the dataset: top view of the soundings coloured by elevation z (m)
    with the survey lines drawn as arrows (direction of travel, from the first to the last ping of
    each line), and beside it a histogram of elevations, seabed and object soundings apart.

    scene_npz: `scenes/{scene}.npz` path or loaded dict (xyz, line, ping, label); scene_json: path or
    dict (scene, survey {direction, n_lines}, objects). Returns out_png.
    """
    pts = _points(scene_npz)
    xyz = pts["xyz"]
    scene = read_json(scene_json)
    fig = new_figure(10.0, 5.0)
    ax, axh = fig.subplots(1, 2, width_ratios=[2.6, 1.0])
    idx = _subsample(len(xyz), max_points, seed)
    p = xyz[idx][np.argsort(xyz[idx, 2], kind="stable")]
    vmin, vmax = _height_limits(p[:, 2])
    sc = ax.scatter(p[:, 0], p[:, 1], c=p[:, 2], s=_dot_size(len(p)), cmap=HEIGHT_CMAP, vmin=vmin, vmax=vmax, linewidths=0,
                    rasterized=True)
    for ln, a, b in _line_tracks(pts):
        ax.annotate("", xy=b, xytext=a, arrowprops={"arrowstyle": "-|>", "color": "white", "lw": 2.2})
        ax.annotate("", xy=b, xytext=a, arrowprops={"arrowstyle": "-|>", "color": "black", "lw": 1.0})
        ax.text(*a, f"line {ln}", fontsize=7, ha="left", va="bottom",
                bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.8})
    xlim, ylim = _scene_limits(scene, xyz)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    sv = scene.get("survey", {})
    n_obj = len(scene.get("objects", []))
    ax.set_title(f"scene {scene.get('scene', '')}: {len(xyz):,} soundings, {n_obj} objects\n"
                 f"{sv.get('n_lines', '?')} survey line(s) along {sv.get('direction', '?')}", fontsize=10)
    fig.colorbar(sc, ax=ax, shrink=0.8, label="elevation z (m)")

    z = xyz[:, 2]
    bins = np.linspace(float(z.min()), float(z.max()) + 1e-9, 60) if len(z) else 10
    label = np.asarray(pts.get("label", np.full(len(z), -1)))
    groups = [(z[label < 0], "seabed and rocks", "#9a9a9a"), (z[label >= 0], "objects", class_color("reef_ring"))]
    for (zz, name, col), kind in zip(groups, ("stepfilled", "step")):
        if len(zz):
            axh.hist(zz, bins=bins, histtype=kind, orientation="horizontal", color=col, lw=1.4, label=name)
    axh.set_xscale("log")
    axh.set_xlabel("soundings per bin")
    axh.set_ylabel("elevation z (m)")
    axh.set_title("elevation histogram", fontsize=10)
    axh.legend(fontsize=7)
    return write_figure(fig, out_png)
