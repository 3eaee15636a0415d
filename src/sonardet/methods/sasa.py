"""The learned family: SASA trained on `split.fractions` of the training scenes (`sasa_{fraction}`)
and, as variants, with domain randomisation (`sasa_dr_{fraction}`, config `domain_randomisation`).
Trained once per method, run once per dataset (the model is loaded once for all of its scenes)."""

from __future__ import annotations

import logging
import re
import sys

from ..detect.sasa.config import INFERENCE_KEYS, PRESETS, resolve_params
from ..objects import classes as class_registry
from ..seeds import derive_seed
from .base import Method, MethodFamily, Resources

log = logging.getLogger("sonardet.methods.sasa")


def preset(name: str) -> dict:
    """The parameter preset of `sasa.preset`."""
    return PRESETS[name]


def resolved_params(method: Method, threads: int | None = None) -> dict:
    """The full SASA parameters of a method: its preset updated by its `params`, the seed and the
    classes of the config, and (unless given) the classes' symmetry orders from the class registry."""
    s = method.settings
    given = dict(s["params"])
    if "symmetry_orders" not in given:
        given["symmetry_orders"] = {c: class_registry.get(c).symmetry_order for c in s["classes"]}
    given.update(seed=int(s["seed"]), classes=list(s["classes"]))
    if threads is not None:
        given["num_threads"] = int(threads)
    return resolve_params(given, preset(s["preset"]))


class Sasa(MethodFamily):
    """SASA (3DSSD vote head, S-FPS sampling) in pure PyTorch (sonardet.detect.sasa)."""

    name = "sasa"
    label = "SASA"
    prefix = "sasa_"
    group = "main"
    styles = {
        "sasa_25": {"color": "#56B4E9", "linestyle": "-.", "marker": "v"},
        "sasa_50": {"color": "#009E73", "linestyle": "-.", "marker": "^"},
        "sasa_100": {"color": "#0072B2", "linestyle": ":", "marker": "P"},
    }

    def enabled(self, config: dict) -> bool:
        return bool(config["sasa"]["enabled"])

    def fractions(self, config: dict) -> list[int]:
        return [int(f) for f in config["split"]["fractions"]]

    def settings(self, config: dict) -> dict:
        sasa = config["sasa"]
        return {"preset": sasa["preset"], "device": sasa["device"], "params": dict(sasa["params"]),
                "seed": int(config["seed"]), "classes": list(config["classes"])}

    def variant_of(self, fraction: int) -> str | None:
        return None

    def _method(self, fraction: int, config: dict) -> Method:
        return Method(name=f"{self.prefix}{fraction}", family=self.name, settings=self.settings(config),
                      runner="per_dataset", trained=True, fraction=int(fraction),
                      variant_of=self.variant_of(fraction), resources=("model",),
                      threads=int(config["sasa"]["threads"]), group=self.group)

    def methods(self, config: dict) -> list[Method]:
        if not self.enabled(config):
            return []
        return [self._method(f, config) for f in self.fractions(config)]

    def parse(self, name: str, config: dict) -> Method | None:
        m = re.fullmatch(rf"{self.prefix}(\d+)", name)
        return self._method(int(m.group(1)), config) if m else None

    def check(self, config: dict) -> list[str]:
        s = config["sasa"]
        out = [f"sasa.params.{key}: set by the top-level key `{key}`; remove it here"
               for key in ("seed", "classes") if key in s["params"]]
        try:
            resolve_params(s["params"], preset(s["preset"]))
        except (ValueError, TypeError) as exc:
            out.append(f"sasa.params: {exc}")
        return out

    def check_params(self, method: Method) -> None:
        resolved_params(method)

    def ablation_method(self, point: dict, config: dict) -> Method:
        m = self._method(int(point.get("fraction", 100)), config)
        return m.with_settings(params=dict(point.get("params") or {}))

    def _device(self, method: Method, resources: Resources):
        device = resources.device if resources.device != "auto" else method.settings["device"]
        return None if device == "auto" else device

    def _inference_params(self, method: Method, resources: Resources) -> dict:
        params = {"num_threads": int(resources.threads), "progress": False}
        params.update({k: v for k, v in method.settings["params"].items() if k in INFERENCE_KEYS})
        return params

    def load(self, method: Method, resources: Resources):
        """The trained model (TrainedSASA), loaded once, then called on each point cloud."""
        from ..detect.sasa import TrainedSASA

        return TrainedSASA.load(resources.model_path, self._inference_params(method, resources),
                                self._device(method, resources))

    def dataset_share_key(self, method: Method) -> str | None:
        """Every SASA model (any training fraction, seed or domain randomisation) on one device: one job
        per dataset reads and prepares each scene once for all of them (`infer_models`)."""
        return f"sasa-inference:{method.settings['device']}"

    def detect_dataset(self, method: Method, resources: Resources, scene_paths) -> tuple[dict, dict]:
        return self.detect_datasets([method], [resources], scene_paths)[0]

    def detect_datasets(self, methods: list[Method], resources: list[Resources],
                        scene_paths) -> list[tuple[dict, dict]]:
        from ..detect.sasa import TrainedSASA, infer_models

        models = [TrainedSASA.load(r.model_path, self._inference_params(m, r), self._device(m, r))
                  for m, r in zip(methods, resources)]
        return infer_models(models, list(scene_paths))

    def train(self, method: Method, train_paths, val_paths, out_dir, resources: Resources) -> dict:
        from ..detect.sasa import ConfigMismatchError, train

        params = resolved_params(method, threads=resources.threads)
        # A progress bar in a log file is noise.
        params["progress"] = sys.stderr.isatty() and params["progress"]
        device = self._device(method, resources)
        log.info("training %s on %d scenes (fraction %s %%), %d validation scenes, %d epochs, batch %d, device %s",
                 method.name, len(train_paths), method.fraction, len(val_paths), params["epochs"],
                 params["batch_size"], method.settings["device"])
        try:
            return train(list(train_paths), list(val_paths), params, out_dir, device=device, resume=True)
        except ConfigMismatchError as exc:
            # The config changed since the checkpoint was written: it is stale.
            log.warning("%s; starting afresh", exc)
            return train(list(train_paths), list(val_paths), params, out_dir, device=device, resume=False)


class SasaSeeds(Sasa):
    """The largest training fraction trained again with other seeds (`sasa.seeds` in all, the first
    being the main model): `sasa_{fraction}_seed{k}`, k = 1 .. seeds - 1, reported as mean and spread."""

    name = "sasa_seed"
    label = "SASA"
    prefix = "sasa_seed"
    group = "seeds"
    styles = {}

    def fractions(self, config: dict) -> list[int]:
        return [max(int(f) for f in config["split"]["fractions"])]

    def methods(self, config: dict) -> list[Method]:
        if not self.enabled(config):
            return []
        f = self.fractions(config)[0]
        return [self._seeded(f, k, config) for k in range(1, int(config["sasa"]["seeds"]))]

    def _seeded(self, fraction: int, k: int, config: dict) -> Method:
        m = self._method(fraction, config)
        settings = {**m.settings, "seed": derive_seed(config["seed"], "sasa seed", k) % 2**31}
        return Method(**{**m.to_dict(), "name": f"sasa_{fraction}_seed{k}", "settings": settings,
                         "variant_of": f"sasa_{fraction}", "resources": ("model",), "datasets": ("synthetic",)})

    def parse(self, name: str, config: dict) -> Method | None:
        m = re.fullmatch(r"sasa_(\d+)_seed(\d+)", name)
        return self._seeded(int(m.group(1)), int(m.group(2)), config) if m else None


class SasaDomainRandomised(Sasa):
    """SASA trained with randomised sensor effects (`dr_*` keys), a variant of `sasa_{fraction}`."""

    name = "sasa_dr"
    label = "SASA"
    prefix = "sasa_dr_"
    group = "domain_randomisation"
    styles = {}

    def enabled(self, config: dict) -> bool:
        return bool(config["sasa"]["enabled"] and config["domain_randomisation"]["enabled"])

    def fractions(self, config: dict) -> list[int]:
        return [int(f) for f in config["domain_randomisation"]["fractions"]]

    def settings(self, config: dict) -> dict:
        s = super().settings(config)
        s["params"] = {**s["params"], **config["domain_randomisation"]["params"], "dr_enabled": True}
        return s

    def variant_of(self, fraction: int) -> str | None:
        return f"sasa_{fraction}"

    def check(self, config: dict) -> list[str]:
        dr = config["domain_randomisation"]
        if not dr["enabled"]:
            return []
        bad = [f for f in dr["fractions"] if f not in config["split"]["fractions"]]
        out = [f"domain_randomisation.fractions: {bad} not among split.fractions {config['split']['fractions']}"] \
            if bad else []
        try:
            resolve_params({**config["sasa"]["params"], **dr["params"], "dr_enabled": True},
                           preset(config["sasa"]["preset"]))
        except (ValueError, TypeError) as exc:
            out.append(f"domain_randomisation.params: {exc}")
        return out
