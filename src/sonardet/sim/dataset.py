"""The synthetic dataset: scene ids, train/validation/test split, nested training fractions, statistics."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ..io.artifacts import read_json_file, read_text_file
from ..seeds import derive_seed


def scene_ids(n_scenes: int) -> list[str]:
    """Scene ids s0000, s0001, ... for n_scenes scenes."""
    return [f"s{i:04d}" for i in range(n_scenes)]


def split_names(fractions) -> list[str]:
    """Names of the split files: train, dev, test and train_{f} per training fraction f (%)."""
    return ["train", "dev", "test"] + [f"train_{int(f)}" for f in fractions]


def make_splits(ids: list[str], n_test: int, n_dev: int, fractions, seed: int) -> dict[str, list[str]]:
    """Seeded split of the scene ids (the study's pool first, then the development scenes).

    The last n_dev ids are `dev`: scenes generated like the others, disjoint from every training
    fraction and from `test`, for every choice a method makes (thresholds, epochs, checkpoints, the
    ablations). The other ids are the study's pool: `test` (n_test scenes, read only by the final
    evaluation) and `train` (the rest); `train_{f}` is the first ceil(f% of train) scenes of one
    fixed random order of the training pool, so smaller fractions are nested in larger ones (25
    within 50 within 100). The pool's split does not depend on n_dev.
    """
    if n_dev < 0 or n_dev >= len(ids):
        raise ValueError(f"split.n_dev ({n_dev}) must be in [0, {len(ids)}) (the scene ids)")
    pool_ids, dev = list(ids[: len(ids) - n_dev]), list(ids[len(ids) - n_dev:])
    if n_test >= len(pool_ids):
        raise ValueError(f"split.n_test ({n_test}) must be smaller than scenes.n_scenes ({len(pool_ids)})")
    rng = np.random.default_rng(derive_seed(seed, "split"))
    perm = [pool_ids[i] for i in rng.permutation(len(pool_ids))]
    test, pool = perm[:n_test], perm[n_test:]
    out = {"test": sorted(test), "train": sorted(pool), "dev": sorted(dev)}
    order = [pool[i] for i in np.random.default_rng(derive_seed(seed, "fractions")).permutation(len(pool))]
    for f in fractions:
        out[f"train_{int(f)}"] = sorted(order[: max(1, math.ceil(len(pool) * f / 100.0))])
    return out


def read_split(path) -> list[str]:
    """Scene ids listed in a split file (one per line)."""
    return [s for s in read_text_file(path, "split file").split() if s]


def dataset_stats(scene_jsons: dict[str, dict], splits: dict[str, list[str]], classes: list[str]) -> pd.DataFrame:
    """The source study's dataset table: per split (train, test, all = train + test, the study's
    pool; then dev, the development scenes) the number of scenes, objects (visible ones, as
    evaluated) and per-class counts and shares (%)."""
    rows = []
    pool = sorted(set(splits["train"]) | set(splits["test"]))
    for name, ids in (("train", splits["train"]), ("test", splits["test"]), ("all", pool),
                      ("dev", splits.get("dev", []))):
        objs = [o for s in ids for o in scene_jsons[s]["objects"] if o["visible"]]
        row = {"split": name, "scenes": len(ids), "objects": len(objs),
               "objects_not_visible": sum(1 for s in ids for o in scene_jsons[s]["objects"] if not o["visible"])}
        for c in classes:
            n = sum(1 for o in objs if o["cls"] == c)
            row[f"{c}"] = n
            row[f"{c}_share_pct"] = round(100.0 * n / len(objs), 1) if objs else 0.0
        rows.append(row)
    return pd.DataFrame(rows)


def read_scene_meta(path) -> dict:
    """Read a scene JSON (validation of the contract lives in sonardet.io.annotations)."""
    return read_json_file(path, "scene annotations file")
