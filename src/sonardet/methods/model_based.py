"""The model-based (training-free) family: `model_based_{variant}` for each variant in
`model_based.variants` (paper, ours), run per scene, parameters from `model_based.{variant}` over the
variant's defaults (sonardet.detect.model_based.params)."""

from __future__ import annotations

import json
import re

import numpy as np

from ..detect.model_based import VARIANTS, resolve_params
from .base import Method, MethodFamily, Resources

PREFIX = "model_based_"


class ModelBased(MethodFamily):
    """Seabed removal, proposals, ICP of the class models, scoring, duplicate removal; no training."""

    name = "model_based"
    label = "model-based"
    prefix = PREFIX
    styles = {
        "model_based_paper": {"color": "#E69F00", "linestyle": "--", "marker": "o"},
        "model_based_ours": {"color": "#D55E00", "linestyle": "--", "marker": "D"},
    }

    def _method(self, variant: str, params: dict) -> Method:
        return Method(name=f"{PREFIX}{variant}", family=self.name,
                      settings={"variant": variant, "params": dict(params or {})})

    def _step(self, step: dict, config: dict) -> Method:
        """A step of the improvement ladder: its base variant's settings with the step's overrides, run
        on the synthetic test set only."""
        params = {**config["model_based"][step["base"]], **step.get("params", {})}
        return Method(name=f"{PREFIX}{step['name']}", family=self.name, group="ladder", datasets=("synthetic",),
                      settings={"variant": step["base"], "params": params, "step": step["step"]})

    def methods(self, config: dict) -> list[Method]:
        mb = config["model_based"]
        return [self._method(v, mb[v]) for v in mb["variants"]] + [self._step(s, config) for s in mb["ladder"]]

    def parse(self, name: str, config: dict) -> Method | None:
        for step in config["model_based"]["ladder"]:
            if name == f"{PREFIX}{step['name']}":
                return self._step(step, config)
        m = re.fullmatch(rf"{PREFIX}(\w+)", name)
        if not m or m.group(1) not in VARIANTS:
            return None
        return self._method(m.group(1), config["model_based"].get(m.group(1), {}))

    def check(self, config: dict) -> list[str]:
        out = []
        for variant in VARIANTS:
            try:
                resolve_params(config["model_based"][variant], variant)
            except (ValueError, TypeError) as exc:
                out.append(f"model_based.{variant}: {exc}")
        names = list(VARIANTS)
        for i, step in enumerate(config["model_based"]["ladder"]):
            where = f"model_based.ladder[{i}] ({step['name']})"
            if step["name"] in names:
                out.append(f"{where}.name: {step['name']!r} is already a variant or step")
            names.append(step["name"])
            try:
                resolve_params(self._step(step, config).settings["params"], step["base"])
            except (ValueError, TypeError) as exc:
                out.append(f"{where}.params: {exc}")
        return out

    def check_params(self, method: Method) -> None:
        resolve_params(method.settings["params"], method.settings["variant"])

    def share_key(self, method: Method) -> str | None:
        """'paper' settings equal outside `paper.RANKING_KEYS` (e.g. the study's ranking and the ladder's
        tight-fitness step) share the seabed, windows and registrations of a scene; 'ours' runs alone."""
        if method.settings["variant"] != "paper":
            return None
        from ..detect.model_based.paper import RANKING_KEYS

        p = resolve_params(method.settings["params"], "paper")
        return "paper:" + json.dumps({k: v for k, v in p.items() if k not in RANKING_KEYS}, sort_keys=True)

    def load_shared(self, methods: list[Method], resources: Resources):
        """One 'paper' detector registering each scene once for all `methods` (same share key), ranking
        the fits for each (`ModelBasedDetector.rankings`); a single method (either variant) runs on its
        own detector."""
        if len(methods) == 1:
            return super().load_shared(methods, resources)
        from ..detect.model_based import ModelBasedDetector
        from ..detect.model_based.paper import RANKING_KEYS

        keys = {self.share_key(m) for m in methods}
        if len(keys) != 1 or None in keys:
            raise ValueError(f"methods {[m.name for m in methods]} do not share a run (different share keys)")
        params = [resolve_params(m.settings["params"], "paper") for m in methods]
        detector = ModelBasedDetector(resources.templates, resources.objects, methods[0].settings["params"], "paper",
                                      threads=resources.threads)
        return _SharedRankings(detector, [{k: p[k] for k in RANKING_KEYS} for p in params])

    def load(self, method: Method, resources: Resources):
        """A ModelBasedDetector: the class models are built once (its `build_seconds`), then it runs on
        each point cloud, `ours` fitting on `resources.threads` worker threads."""
        from ..detect.model_based import ModelBasedDetector

        return ModelBasedDetector(resources.templates, resources.objects, method.settings["params"],
                                  method.settings["variant"], threads=resources.threads)


class _SharedRankings:
    """A 'paper' detector called for several rankings at once: xyz -> [(detections, stats)] per ranking."""

    def __init__(self, detector, overrides: list[dict]):
        self.detector, self.overrides = detector, overrides
        self.build_seconds = detector.build_seconds

    def __call__(self, xyz: np.ndarray) -> list:
        return self.detector.rankings(xyz, self.overrides)
