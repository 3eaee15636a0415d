"""The model-based (training-free) family: `model_based_{variant}` for each variant in
`model_based.variants` (paper, ours), run per scene, parameters from `model_based.{variant}` over the
variant's defaults (sonardet.detect.model_based.params)."""

from __future__ import annotations

import re

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

    def load(self, method: Method, resources: Resources):
        """A ModelBasedDetector: the class models are built once (its `build_seconds`), then it runs on
        each point cloud, `ours` fitting on `resources.threads` worker threads."""
        from ..detect.model_based import ModelBasedDetector

        return ModelBasedDetector(resources.templates, resources.objects, method.settings["params"],
                                  method.settings["variant"], threads=resources.threads)
