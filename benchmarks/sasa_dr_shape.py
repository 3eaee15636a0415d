"""SASA with and without the shape perturbations of its domain randomisation (``dr_shape_prob``),
trained alike and scored on the development scenes and the mismatch development scenes.

Both variants train the `sasa` family at one training fraction with domain randomisation on
(`dr_enabled`), the same seed, a fixed number of epochs without early stopping (equal budget), then
detect on `dev` (results/splits/dev.txt) and `mismatch_dev` (its first `mismatch_test.n_dev` scenes
rebuilt with perturbed objects, results/mismatch/scenes); the test sets are never read. Each variant
is one ablation point (`sonardet.experiments.ablation.run_point`), its model kept under --work.

    python benchmarks/sasa_dr_shape.py --results <run>/results [--fraction 25] [--epochs 20]
                                       [--prob 0.5] [--work sasa_dr_shape] [--json out.json]

One training seed per variant: read a difference against the seed-to-seed spread of the SASA rows in
README (several points of mAP at this budget), not as a ranking.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from sonardet.config import read_config
from sonardet.experiments.ablation import point_method, run_point
from sonardet.methods import Resources


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=Path, required=True, help="a finished run's results folder")
    ap.add_argument("--config", type=Path, default=Path("config/config.yaml"))
    ap.add_argument("--fraction", type=int, default=25)
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--prob", type=float, default=0.5, help="dr_shape_prob of the shape variant")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--work", type=Path, default=Path("sasa_dr_shape"))
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    cfg = read_config(args.config)
    r = args.results
    classes = list(cfg["classes"])

    def split(name: str) -> list[str]:
        return (r / "splits" / f"{name}.txt").read_text().split()

    train = [str(r / "scenes" / f"{s}.npz") for s in split(f"train_{args.fraction}")]
    dev = split("dev")
    mm = dev[: int(cfg["mismatch_test"]["n_dev"])]
    sets = {"mismatch_dev": ([str(r / "mismatch" / "scenes" / f"{s}.npz") for s in mm],
                             [str(r / "mismatch" / "scenes" / f"{s}.json") for s in mm])}
    missing = [p for p in sets["mismatch_dev"][0] if not os.path.exists(p)]
    if missing:
        raise SystemExit(f"{missing[0]}: no such mismatch_dev scene ({len(missing)} of {len(mm)} missing); make the "
                         "development sets first: `snakemake --cores 2 development`")
    objects = [str(r / "objects" / f"{c}.json") for c in classes]
    rows = []
    for name, prob in (("dr", 0.0), ("dr_shape", args.prob)):
        point = {"name": f"sasa{args.fraction}_{name}_e{args.epochs}", "method": "sasa", "fraction": args.fraction,
                 "params": {"epochs": args.epochs, "early_stop_patience": 0, "dr_enabled": True,
                            "dr_shape_prob": prob}}
        method = point_method(point, cfg)
        res = run_point(point, method, [str(r / "scenes" / f"{s}.npz") for s in dev],
                        [str(r / "scenes" / f"{s}.json") for s in dev], classes, cfg["evaluation"], objects,
                        Resources(threads=args.threads), args.work / point["name"], train_npzs=train,
                        other_sets=sets)
        rows.append(res)
        o = res["other_sets"]["mismatch_dev"]
        print(f"{point['name']}: dev mAP {res['mAP']:.3f}, mismatch_dev mAP {o['mAP']:.3f} "
              f"({', '.join(f'{c} {v:.3f}' for c, v in o['AP'].items())}), training {res['train_time_s']:.0f} s; "
              f"load {' '.join(f'{v:.1f}' for v in os.getloadavg())}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
