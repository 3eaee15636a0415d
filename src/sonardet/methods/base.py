"""What a detection method is to the rest of the project: :class:`Method` (one configured method),
:class:`MethodFamily` (how methods of one kind are named, made from the config, run, trained and
timed) and :class:`Resources` (what a method needs to run: object models, template scans, a model
file).

A detector, as returned by :meth:`MethodFamily.load`, is a callable ``detector(xyz) -> (detections,
stats)``: xyz (N,3) float64 metres in any frame (scene or survey CRS, z up); detections a list of
{cls, box [x,y,z,l,w,h,yaw], score, pose (optional), extras (optional)} in the same frame; stats a
JSON-ready dict with at least ``seconds: {"total": s}``.
"""

from __future__ import annotations

import copy
import re
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..io.scenes import read_scene_points

#: How a method's time is recorded in the workflow: a stats file per scene with the scene's seconds
#: (`per_scene`) or one timing file per dataset (`per_dataset`). Either way the workflow runs a
#: method on a dataset's scenes in one job (the detector built or the model loaded once).
RUNNERS = ("per_scene", "per_dataset")
#: Inputs a method can need: the classes' object models, their template scans, a trained model file.
RESOURCE_KINDS = ("objects", "templates", "model")

Detector = Callable[[np.ndarray], tuple[list, dict]]


@dataclass(frozen=True)
class Method:
    """One configured detection method.

    name: unique id (paths, tables), e.g. 'model_based_ours', 'sasa_100'. family: the registry key of
    its family. settings: the JSON-ready parameters its jobs need (a change reruns them). runner: one
    of RUNNERS. trained: whether it is trained (then `fraction`, in %, names the training split
    `train_{fraction}`). variant_of: for a variant of another method (e.g. SASA with domain
    randomisation of 'sasa_100'), that method's name, which the report pairs it with. resources: what
    it needs (RESOURCE_KINDS). threads: CPU threads of its jobs. group: the report table it belongs to
    ('main': the comparison; others, e.g. 'domain_randomisation', 'ladder', 'seeds': their own
    table). datasets: the evaluation datasets it runs on (None: all of them).
    """

    name: str
    family: str
    settings: dict = field(default_factory=dict)
    runner: str = "per_scene"
    trained: bool = False
    fraction: int | None = None
    variant_of: str | None = None
    resources: tuple = ("objects", "templates")
    threads: int = 1
    group: str = "main"
    datasets: tuple | None = None

    def __post_init__(self):
        if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", self.name):
            raise ValueError(f"method name {self.name!r}: use letters, digits and '_' (it names folders)")
        if self.runner not in RUNNERS:
            raise ValueError(f"method {self.name}: runner {self.runner!r} is not one of {RUNNERS}")
        bad = [r for r in self.resources if r not in RESOURCE_KINDS]
        if bad:
            raise ValueError(f"method {self.name}: unknown resources {bad}; use {RESOURCE_KINDS}")
        if self.trained and self.fraction is None:
            raise ValueError(f"method {self.name}: a trained method needs a training fraction")

    def to_dict(self) -> dict:
        """JSON-ready form (what the workflow passes to its jobs)."""
        d = asdict(self)
        d["resources"] = list(self.resources)
        d["datasets"] = None if self.datasets is None else list(self.datasets)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Method":
        """Inverse of :meth:`to_dict`."""
        d = dict(d)
        d["resources"] = tuple(d.get("resources", ()))
        d["datasets"] = None if d.get("datasets") is None else tuple(d["datasets"])
        return cls(**d)

    def runs_on(self, dataset: str) -> bool:
        """Whether the method is run and evaluated on `dataset`."""
        return self.datasets is None or dataset in self.datasets

    def with_settings(self, **changes) -> "Method":
        """A copy with other settings (deep-merged one level: dict values are updated, not replaced)."""
        s = copy.deepcopy(self.settings)
        for k, v in changes.items():
            s[k] = {**s[k], **v} if isinstance(s.get(k), dict) and isinstance(v, dict) else v
        return Method(**{**asdict(self), "settings": s, "resources": self.resources, "datasets": self.datasets})


@dataclass
class Resources:
    """What a method runs with: object models (class -> ObjectInfo), template scans (class ->
    TemplateViews), a trained model file, the torch device ('auto', 'cpu', 'cuda') and CPU threads."""

    objects: dict | None = None
    templates: dict | None = None
    model_path: Path | None = None
    device: str = "auto"
    threads: int = 1


class MethodFamily:
    """Base class of a family of methods; a family registers one instance (``methods.register``).

    Subclasses set `name` (registry key), `label` (its name in report tables, e.g. 'model-based'),
    `prefix` (the start of its methods' names) and implement :meth:`methods`, :meth:`parse` and
    :meth:`load`; trained families also :meth:`train`. The defaults here suit a per-scene, untrained detector.
    """

    name: str = ""
    label: str = ""
    #: The start of its methods' names (used to tell a method's family from its name in figures).
    prefix: str = ""
    #: Report styles of named methods (colour, linestyle, marker); others get a stable spare colour.
    styles: dict = {}

    def methods(self, config: dict) -> list[Method]:
        """The methods of this family that the validated config asks for, in config order."""
        return []

    def parse(self, name: str, config: dict) -> Method | None:
        """The method called `name` if it belongs to this family (also when the config does not list
        it, e.g. `sasa_30` for a model trained elsewhere), else None."""
        return next((m for m in self.methods(config) if m.name == name), None)

    def check(self, config: dict) -> list[str]:
        """Problems of this family's config sections, each naming the key (empty list: fine)."""
        return []

    def load(self, method: Method, resources: Resources) -> Detector:
        """A detector for `method`: a callable xyz (N,3) float64 -> (detections, stats)."""
        raise NotImplementedError(f"method family {self.name!r} cannot run")

    def share_key(self, method: Method) -> str | None:
        """Methods of this family with the same key (not None) do the same work on a scene up to a late
        step (e.g. the same registrations, ranked differently): the workflow runs them on a dataset in
        one job (:meth:`load_shared`). Default None: every method runs on its own."""
        return None

    def load_shared(self, methods: list[Method], resources: Resources) -> Callable[[np.ndarray], list]:
        """One detector for methods of one :meth:`share_key` (or a single method): xyz -> a list of
        (detections, stats), one per method in order, each the detections of the method's own detector
        (:meth:`load`); its ``build_seconds`` is the time its models took. Default: each method's
        detector in turn."""
        return _InTurn([self.load(m, resources) for m in methods])

    def dataset_share_key(self, method: Method) -> str | None:
        """Per-dataset methods, of any family, with the same key (not None) run on a dataset in one job
        through :meth:`detect_datasets` of the first one's family, which does the work they have in
        common once (e.g. reading and preparing each scene for several trained models): the key names
        the implementation that runs them. Default None: a job per method."""
        return None

    def detect_datasets(self, methods: list[Method], resources: list[Resources],
                        scene_paths) -> list[tuple[dict, dict]]:
        """:meth:`detect_dataset` of each method (with its own Resources), in order, each result the
        same as the method's own. Default: one after the other."""
        return [self.detect_dataset(m, r, scene_paths) for m, r in zip(methods, resources)]

    def detect_dataset(self, method: Method, resources: Resources, scene_paths) -> tuple[dict, dict]:
        """Detections of every scene file (scene id -> list) and a timing dict {n_scenes,
        s_per_scene, s_max}. Default: load once, then the detector on each scene's soundings."""
        detector = self.load(method, resources)
        out, secs = {}, []
        for p in scene_paths:
            xyz = read_scene_points(p)["xyz"]
            t0 = time.perf_counter()
            out[Path(p).stem], _ = detector(xyz)
            secs.append(time.perf_counter() - t0)
        return out, {"n_scenes": len(secs), "s_per_scene": float(np.mean(secs)) if secs else None,
                     "s_max": float(np.max(secs)) if secs else None}

    def train(self, method: Method, train_paths, val_paths, out_dir, resources: Resources) -> dict:
        """Train `method` on the training scene files into out_dir (model.pt, loss.csv, train.json);
        returns the training summary (train_time_s, steps, s_per_step, peak_rss_mb, ...)."""
        raise NotImplementedError(f"method family {self.name!r} is not trained")

    def ablation_method(self, point: dict, config: dict) -> Method:
        """The method of an ablation grid point {name, method, params, fraction}: the configured one
        with `params` on top of its settings."""
        m = self.parse(point["method"], config)
        if m is None:
            raise ValueError(f"ablation point {point['name']!r}: method {point['method']!r} is not one of family "
                             f"{self.name!r}")
        return m.with_settings(params=dict(point.get("params") or {}))

    def check_params(self, method: Method) -> None:
        """Raise ValueError if the method's settings are invalid (unknown or bad parameters)."""

    def training_label(self, method: Method) -> str:
        """How the report's fraction table describes the method's training."""
        return f"{self.label}, {method.fraction} % of the training split" if method.trained else "no training"

    def style(self, method: Method) -> dict | None:
        """Colour, linestyle and marker of the method in figures (None: a stable spare style)."""
        return self.styles.get(method.name)


class _InTurn:
    """Detectors called one after the other on a cloud: xyz -> [(detections, stats)] in their order."""

    def __init__(self, detectors: list):
        self.detectors = detectors
        self.build_seconds = sum(float(getattr(d, "build_seconds", 0.0)) for d in detectors)

    def __call__(self, xyz: np.ndarray) -> list:
        return [d(xyz) for d in self.detectors]
