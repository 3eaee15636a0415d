"""Run sonardet's evaluation (`sonardet.eval.evaluate`) on the peer check's cases read as JSON from stdin.

tests/test_eval_devkit_peer.py runs this in a fresh process with the pinned numerical environment of
`sonardet.determinism` (as the workflow's evaluation jobs run), and the devkit's runner in the same
environment: the centre distances go through BLAS `ddot`, whose last bit depends on the kernels
OpenBLAS picks for the CPU, and the two processes hold different OpenBLAS builds (numpy 2 here, numpy 1
in the devkit's venv). Unpinned, on a CPU where the two builds pick different kernels, a pair lying
within an ulp of a threshold is matched by one and not by the other.

Input (stdin)::

    {"classes": [...], "thresholds": [...], "symmetric": [...],
     "cases": [{"gt": {...}, "dets": {...}, "tp_threshold": <float>, "barrier_class": <class or null>}]}

Output (stdout): {"results": [{"per_class": {cls: {"AP": {...}, "tp_errors": {...}}},
"pr_curves": {cls: {threshold key: {"precision": [...], "confidence": [...]}}}}]}, floats exactly as
computed (JSON keeps a float64's shortest repr, which reads back to the same value).
"""

import json
import math
import sys

import numpy as np

from sonardet.eval import evaluate


def _plain(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(f"not serialisable: {type(x)}")


def main() -> None:
    req = json.load(sys.stdin)
    out = []
    for case in req["cases"]:
        periods = {case["barrier_class"]: math.pi} if case.get("barrier_class") else None
        res = evaluate(case["gt"], case["dets"], req["classes"], req["thresholds"], case["tp_threshold"],
                       req["symmetric"], yaw_periods_rad=periods)
        out.append({"per_class": {c: {"AP": v["AP"], "tp_errors": v["tp_errors"]} for c, v in res["per_class"].items()},
                    "pr_curves": res["pr_curves"]})
    json.dump({"results": out}, sys.stdout, default=_plain)


if __name__ == "__main__":
    main()
