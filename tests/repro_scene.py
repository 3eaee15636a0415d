"""Digests of a small scene made from scratch (the smoke config's object meshes, template scans and scene
s0000), for tests/test_reproducibility.py: a change of behaviour of the simulator, of the meshes or of
a numerical library shows up as a changed digest.

    python tests/repro_scene.py            # print the digests (JSON)
    python tests/repro_scene.py --update   # rewrite tests/data/repro_digests.json (after a deliberate change)
    python tests/repro_scene.py --record-kind NAME  # record the digests that differ on this kind of CPU
                                                    # (tests/data/repro_digests_cpu_kinds.json)

Each digest is a SHA-256 of values rounded to a grid far above floating-point noise (soundings and
template points to 0.1 mm, poses to 0.1 mm / 1e-6, mesh vertices to 1 nm) together with the exact
integers (pings, beams, lines, labels, faces, visibility), so it does not depend on the file format's
bytes, only on what the simulation made. `bytes` holds the files' own SHA-256 for information.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
EXPECTED = ROOT / "tests" / "data" / "repro_digests.json"
#: Digests that differ on other kinds of CPU (the ray caster's last bits; `sonardet.determinism`), per kind.
KINDS = ROOT / "tests" / "data" / "repro_digests_cpu_kinds.json"


def _sha(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()


def _grid(x, step: float) -> np.ndarray:
    return np.round(np.asarray(x, dtype=np.float64) / step).astype(np.int64)


def digests(work: Path) -> dict:
    """Build the smoke config's objects, templates and scene s0000 in `work`; their digests."""
    import os

    from sonardet.config import read_config
    from sonardet.io.scenes import read_scene_points, write_scene
    from sonardet.io.templates import write_templates
    from sonardet.objects import build_object, read_object, write_object
    from sonardet.seeds import derive_seed
    from sonardet.sim.mbes import SensorConfig
    from sonardet.sim.scene import simulate_scene
    from sonardet.sim.templates import scan_templates

    os.chdir(ROOT)  # the smoke config names its plugins relative to the repository
    cfg = read_config(ROOT / "tests" / "config" / "smoke.yaml")
    out, files = {}, {}
    for c in cfg["classes"]:
        ply, js = work / f"{c}.ply", work / f"{c}.json"
        write_object(build_object(c, cfg["objects"]), cfg["objects"]["density_kg_m3"], ply, js)
        obj = read_object(js)
        out[f"mesh/{c}"] = _sha(_grid(obj.mesh.vertices, 1e-9), np.asarray(obj.mesh.faces))
        tv = scan_templates(c, obj.mesh.vertices, obj.mesh.faces, obj.symmetry_order, cfg["templates"],
                            SensorConfig.from_dict(cfg["sensor"]),
                            np.random.default_rng(derive_seed(cfg["seed"], "template", c)))
        write_templates(work / f"templates_{c}.npz", tv)
        out[f"templates/{c}"] = _sha(_grid(tv.xyz, 1e-4), tv.view, tv.ping, tv.beam)
        files[ply.name] = ply
    objects = {c: read_object(work / f"{c}.json") for c in cfg["classes"]}
    scene = simulate_scene("s0000", cfg, objects)
    write_scene(scene, work / "s0000.npz", work / "s0000.json")
    pts = read_scene_points(work / "s0000.npz")
    out["scene/s0000/soundings"] = _sha(_grid(pts["xyz"], 1e-4), pts["ping"], pts["beam"], pts["line"], pts["label"])
    meta = json.loads((work / "s0000.json").read_text())
    objs = [(o["id"], o["cls"], _grid(o["pose"]["t"], 1e-4).tolist(), _grid(o["pose"]["q"], 1e-6).tolist(),
             o["n_points"], o["visible"]) for o in meta["objects"]]
    out["scene/s0000/objects"] = hashlib.sha256(json.dumps([objs, meta["removed"]], default=str).encode()).hexdigest()
    out["scene/s0000/n_points"] = int(len(pts["xyz"]))
    out["scene/s0000/n_visible"] = int(sum(o["visible"] for o in meta["objects"]))
    files.update({"s0000.npz": work / "s0000.npz"})
    out["bytes"] = {k: hashlib.sha256(p.read_bytes()).hexdigest() for k, p in sorted(files.items())}
    return out


def cpu_model() -> str:
    """The CPU's model name and its AVX-512 flags, for the record of a kind."""
    from sonardet.determinism import cpu_flags
    from sonardet.report.summary import machine_info

    avx512 = " ".join(sorted(f for f in cpu_flags() if f.startswith("avx512"))) or "no AVX-512"
    return f"{machine_info()['cpu_model']}; {avx512}"


def differing(expected: dict, got: dict) -> set:
    """The digest keys (all but the informative "bytes") whose value in `got` differs from `expected`."""
    return {k for k, v in got.items() if k != "bytes" and expected.get(k) != v}


def matching_kind(expected: dict, kinds: dict, got: dict) -> str | None:
    """The name of the recorded CPU kind whose digests explain every difference of `got` from `expected`
    ("reference" when there is none), or None. A kind matches only as a whole: each digest it records
    must equal `got`'s, and every key that differs from the reference must be one of them."""
    differ = differing(expected, got)
    if not differ:
        return "reference"
    for name, rec in kinds.get("kinds", {}).items():
        digests = rec["digests"]
        if differ <= set(digests) and all(got.get(k) == v for k, v in digests.items()):
            return name
    return None


def record_kind(result: dict, kind: str) -> dict:
    """The digests of `result` that differ from EXPECTED's, recorded in KINDS under `kind` with this CPU."""
    expected = json.loads(EXPECTED.read_text())
    kinds = json.loads(KINDS.read_text()) if KINDS.exists() else {"kinds": {}}  # its "note" is kept
    differ = {k: result[k] for k in sorted(differing(expected, result))}
    kinds["kinds"][kind] = {"cpu": cpu_model(), "digests": differ}
    KINDS.write_text(json.dumps(kinds, indent=1, sort_keys=True) + "\n")
    return differ


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as tmp:
        result = digests(Path(tmp))
    text = json.dumps(result, indent=1, sort_keys=True) + "\n"
    if "--update" in sys.argv:
        EXPECTED.write_text(text)
    if "--record-kind" in sys.argv:
        record_kind(result, sys.argv[sys.argv.index("--record-kind") + 1])
    print(text, end="")
