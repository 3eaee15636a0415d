"""Whether two workflow runs made the same outputs: the files README's "Reproducibility" table calls
byte-stable compared byte for byte, and the SASA models' weights tensor for tensor.

Byte for byte (SHA-256): object meshes (`objects/`), template scans (`templates/`), splits
(`splits/`), scene soundings (`*.npz` under `scenes/`, `realism/`, `mismatch/`, `hybrid/`,
`realism_ablation/`), detections (`detections/`) and evaluations (`eval/`). Tensor for tensor: the
`state_dict` of every `model.pt` (the file itself also holds the training's timings, which differ
on every run). Timing files, logs, benchmarks and tables are not compared: they are measurements.

Usage: ``python benchmarks/compare_runs.py RESULTS_A RESULTS_B [--json out.json]``; exit status 0
when every compared output is equal and present in both runs, 1 otherwise (the differing or
missing files are listed, the first ten per group).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

#: (group name, folder under results, glob pattern) of the byte-stable outputs.
BYTE_GROUPS = (
    ("object meshes", "objects", "**/*"),
    ("template scans", "templates", "**/*"),
    ("splits", "splits", "**/*"),
    ("scene soundings", "scenes", "*.npz"),
    ("realism scenes", "realism", "**/*.npz"),
    ("mismatch scenes", "mismatch", "**/*.npz"),
    ("hybrid scenes", "hybrid", "**/*.npz"),
    ("realism-ablation scenes", "realism_ablation", "**/*.npz"),
    ("detections", "detections", "**/*"),
    ("evaluations", "eval", "**/*"),
)
SHOW = 10


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _files(root: Path, folder: str, pattern: str) -> set[str]:
    base = root / folder
    return {p.relative_to(root).as_posix() for p in base.glob(pattern) if p.is_file()} if base.is_dir() else set()


def compare_files(a: Path, b: Path, folder: str, pattern: str) -> dict:
    """Files of one group in runs `a` and `b` (results folders): counts, and the relative paths only in
    one run or with different bytes."""
    fa, fb = _files(a, folder, pattern), _files(b, folder, pattern)
    both = sorted(fa & fb)
    return {"files_a": len(fa), "files_b": len(fb), "only_a": sorted(fa - fb), "only_b": sorted(fb - fa),
            "differ": [f for f in both if _digest(a / f) != _digest(b / f)]}


def _state_dict(path: Path) -> dict:
    import torch

    doc = torch.load(path, map_location="cpu", weights_only=False)
    if not isinstance(doc, dict) or not isinstance(doc.get("state_dict"), dict):
        raise ValueError(f"{path}: not a SASA model file (no 'state_dict'); was it written by this workflow?")
    return doc["state_dict"]


def compare_models(a: Path, b: Path) -> dict:
    """Every `model.pt` under run `a` against the same path under `b`: equal when both hold the same
    parameter and buffer names with equal tensors (dtype, shape and every value)."""
    import torch

    fa = {p.relative_to(a).as_posix() for p in a.rglob("model.pt")}
    fb = {p.relative_to(b).as_posix() for p in b.rglob("model.pt")}
    differ, tensors = [], 0
    for rel in sorted(fa & fb):
        sa, sb = _state_dict(a / rel), _state_dict(b / rel)
        tensors += len(sa)
        if sa.keys() != sb.keys() or not all(torch.equal(sa[k], sb[k]) for k in sa):
            differ.append(rel)
    return {"files_a": len(fa), "files_b": len(fb), "only_a": sorted(fa - fb), "only_b": sorted(fb - fa),
            "differ": differ, "tensors": tensors}


def compare_runs(a, b) -> dict:
    """Group name -> comparison (`compare_files`, `compare_models` for 'SASA model weights')."""
    a, b = Path(a), Path(b)
    for root in (a, b):
        if not root.is_dir():
            raise FileNotFoundError(f"{root}: no such results folder (give the `results` folder of a finished run)")
    out = {name: compare_files(a, b, folder, pattern) for name, folder, pattern in BYTE_GROUPS}
    out["SASA model weights"] = compare_models(a, b)
    return out


def equal(report: dict) -> bool:
    """Whether every group of `compare_runs` has no differing file and none missing from either run."""
    return all(not (g["only_a"] or g["only_b"] or g["differ"]) for g in report.values())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results_a")
    ap.add_argument("results_b")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    try:
        report = compare_runs(args.results_a, args.results_b)
    except FileNotFoundError as exc:
        print(f"compare_runs.py: {exc}", file=sys.stderr)
        return 2
    for name, g in report.items():
        extra = f", {g['tensors']} tensors" if "tensors" in g else ""
        print(f"{name:24s} {g['files_a']:5d} files in A, {g['files_b']:5d} in B{extra}: {len(g['differ'])} differ, "
              f"{len(g['only_a'])} only in A, {len(g['only_b'])} only in B")
        for key in ("differ", "only_a", "only_b"):
            for rel in g[key][:SHOW]:
                print(f"    {key}: {rel}")
    same = equal(report)
    print("equal: every compared output is the same in both runs" if same else "NOT equal (see above)")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
