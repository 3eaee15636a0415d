"""The object-class registry: one :class:`ClassSpec` per class of reef element.

A spec says everything the project needs to know about a class: how its mesh is built and from which
parameters (with defaults, units and a JSON-schema fragment the config schema is completed with), its
rotational symmetry about the canonical z axis, which canonical axes point up when it rests (a
tetrapod rests on any three of its four legs, so any leg may point up), how it is laid out in scenes
(`arrangement`), which tumbled poses a detector should try on leftovers (`tumble`), its default share
of a scene's objects and its report colour. Everything class-specific elsewhere is derived from the
specs: the config schema's `objects.{cls}` sections and class enums, the packing check's footprints
(from the mesh), SASA's symmetry orders, the scene layout, and, through the object files
(`objects/{cls}.json` carries `up_axes` and `tumble`), the detectors' class-specific branches.

Adding a class: one `register(ClassSpec(...))` (here or in a plugin module listed under `plugins`)
and its name in the config's `classes`.
"""

from __future__ import annotations

import copy
import functools
import json
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .meshes import (
    SYMMETRY_CONTINUOUS,
    ObjectModel,
    build_reef_cone,
    build_reef_ring,
    build_tetrapod,
    tetrapod_leg_directions,
)

#: Scene arrangements a class can have on the reef (see sonardet.sim.layout): hexagonal clusters
#: (scenes.cluster_max, scenes.cone_gap_m), rows stacked in layers over the gaps below (stacks of
#: rings, piles of tetrapods: scenes.pile_max, scenes.pile_layers), single elements spaced apart
#: (scenes.big_spacing_m), or none (scattered only).
ARRANGEMENTS = ("cluster", "stack", "pile", "spaced", "scatter")

#: Tumbled-pose modes: 'stable_poses' (the mesh's own stable resting tilts, trimesh), 'tilts'
#: (given tilts at given azimuths and yaws; for bodies whose every stable pose is upright, such as
#: a tetrapod, which always rests on three legs).
TUMBLE_MODES = ("stable_poses", "tilts")


@dataclass(frozen=True)
class ClassSpec:
    """One class of object (canonical frame: z up, symmetry axis at x = y = 0, lowest point at z = 0).

    name: class id (config, files, labels). build: (class parameters, the config's `objects`
    section) -> ObjectModel. params: JSON-schema properties of the class parameters, each with a
    `default` and a `description` (units in the key names). symmetry_order: 0 = continuous
    (any yaw), n = n-fold about z. up_axes: canonical-frame unit axes; the object rests upright when
    one of them points up. arrangement: one of ARRANGEMENTS; layers: default layers of a stack/pile.
    tumble: {'mode': 'stable_poses'} or {'mode': 'tilts', 'tilts_deg', 'azimuths_n', 'yaws_deg',
    'upright_yaws_deg'}. mix_weight: default relative frequency in scenes. colour: hex colour in
    figures.
    """

    name: str
    build: Callable[[dict, dict], ObjectModel]
    params: dict
    symmetry_order: int
    colour: str
    arrangement: str = "scatter"
    layers: int = 1
    up_axes: tuple = ((0.0, 0.0, 1.0),)
    tumble: dict = field(default_factory=lambda: {"mode": "stable_poses"})
    mix_weight: float = 0.25

    def __post_init__(self):
        if not self.name or not self.name.replace("_", "").isalnum():
            raise ValueError(f"class name {self.name!r}: use letters, digits and '_' (it names files)")
        if self.arrangement not in ARRANGEMENTS:
            raise ValueError(f"class {self.name}: arrangement {self.arrangement!r} is not one of {ARRANGEMENTS}")
        if self.tumble.get("mode") not in TUMBLE_MODES:
            raise ValueError(f"class {self.name}: tumble mode {self.tumble.get('mode')!r} is not one of {TUMBLE_MODES}")
        axes = np.asarray(self.up_axes, dtype=np.float64)
        if axes.ndim != 2 or axes.shape[1] != 3 or not np.allclose(np.linalg.norm(axes, axis=1), 1.0):
            raise ValueError(f"class {self.name}: up_axes must be unit 3-vectors")
        missing = [k for k, v in self.params.items() if "default" not in v]
        if missing:
            raise ValueError(f"class {self.name}: parameters without a default: {missing}")

    def defaults(self) -> dict:
        """The class parameters' defaults (a fresh dict)."""
        return {k: copy.deepcopy(v["default"]) for k, v in self.params.items()}

    def schema(self) -> dict:
        """JSON schema of the class's `objects.{name}` config section."""
        return {"type": "object", "additionalProperties": False, "default": self.defaults(),
                "description": f"parameters of the {self.name} mesh", "properties": copy.deepcopy(self.params)}

    def metadata(self) -> dict:
        """What the object file records of the spec for the detectors (JSON-ready)."""
        return {"up_axes": [[float(v) for v in a] for a in self.up_axes], "tumble": copy.deepcopy(self.tumble)}


_REGISTRY: dict[str, ClassSpec] = {}


def register(spec: ClassSpec) -> ClassSpec:
    """Add a class to the registry (a plugin calls this at import). Re-registering the same name
    replaces the spec (so re-importing a plugin is harmless). Returns the spec."""
    _REGISTRY[spec.name] = spec
    return spec


def get(name: str) -> ClassSpec:
    """The spec of class `name`; KeyError naming the registered classes otherwise."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown object class {name!r}; registered classes: {', '.join(_REGISTRY)} "
                       "(a plugin listed under `plugins` may register more)") from None


def names() -> list[str]:
    """Registered class names, in registration order."""
    return list(_REGISTRY)


def class_params(name: str, objects_cfg: dict) -> dict:
    """The parameters of class `name`: the spec's defaults updated by `objects_cfg[name]`."""
    return {**get(name).defaults(), **dict(objects_cfg.get(name) or {})}


def build_object(name: str, objects_cfg: dict) -> ObjectModel:
    """Build the mesh of class `name` from the config's `objects` section; checks it is watertight
    and has the spec's symmetry."""
    spec = get(name)
    model = spec.build(class_params(name, objects_cfg), objects_cfg)
    if not model.mesh.is_watertight:
        raise RuntimeError(f"{name}: built mesh is not watertight (a boolean failed); try other objects.sections")
    if model.symmetry_order != spec.symmetry_order:
        raise RuntimeError(f"{name}: the builder gave symmetry order {model.symmetry_order}, the spec "
                           f"{spec.symmetry_order}")
    return model


@functools.lru_cache(maxsize=64)
def _coarse_size(name: str, objects_json: str) -> tuple[float, float]:
    v = np.asarray(build_object(name, json.loads(objects_json)).mesh.vertices)
    return float(np.max(np.hypot(*v[:, :2].T))), float(np.ptp(v[:, 2]))


def _coarse_json(objects_cfg: dict) -> str:
    return json.dumps({**objects_cfg, "sections": 16, "holes": False}, sort_keys=True, default=float)


def footprint_radius_m(name: str, objects_cfg: dict) -> float:
    """Largest horizontal distance (m) of the class's mesh from its axis, measured on a coarse build
    (16 facets per circle, no holes; within 1 cm of the full mesh). Cached per parameters."""
    return _coarse_size(name, _coarse_json(objects_cfg))[0]


def height_m(name: str, objects_cfg: dict) -> float:
    """Height (m) of the class's mesh in its resting pose, from the coarse build of `footprint_radius_m`."""
    return _coarse_size(name, _coarse_json(objects_cfg))[1]


# ---------------------------------------------------------------------------------------------
# The four reef elements of the Nienhagen artificial reef.

_POS = {"type": "number", "exclusiveMinimum": 0}


def _tetrapod_params(height_m: float, mass_kg: float) -> dict:
    return {
        "height_m": {**_POS, "default": height_m, "description": "overall height standing on three legs (m)"},
        "mass_kg": {**_POS, "default": mass_kg,
                    "description": "mass (kg); the leg thickness is solved to give this mass at objects.density_kg_m3"},
        "taper": {"type": "number", "exclusiveMinimum": 0, "maximum": 1, "default": 0.6,
                  "description": "leg tip radius / leg root radius"},
    }


def _build_tetrapod(name: str):
    def build(p: dict, objects_cfg: dict) -> ObjectModel:
        return build_tetrapod(name, p["height_m"], p["mass_kg"], objects_cfg["density_kg_m3"], p["taper"],
                              objects_cfg["sections"] // 2)
    return build


def _build_cone(p: dict, objects_cfg: dict) -> ObjectModel:
    return build_reef_cone(p["height_m"], p["base_diameter_m"], p["top_diameter_m"], p["wall_m"], p["n_holes"],
                           tuple(p["hole_diameter_m"]), objects_cfg["holes"], objects_cfg["hole_seed"],
                           objects_cfg["sections"])


def _build_ring(p: dict, objects_cfg: dict) -> ObjectModel:
    return build_reef_ring(p["height_m"], p["outer_diameter_m"], p["outer_wall_m"], p["inner_wall_m"], p["gap_m"],
                           p["outer_holes"], p["outer_hole_diameter_m"], p["inner_holes"],
                           p["inner_hole_diameter_m"], p["n_ribs"], p["rib_m"], objects_cfg["holes"],
                           objects_cfg["sections"])


#: Tetrapods rest on three legs in every stable pose; leftovers in piles are tried at these tilts.
_TETRAPOD_TUMBLE = {"mode": "tilts", "tilts_deg": [30.0, 55.0], "azimuths_n": 6, "yaws_deg": [0.0, 60.0],
                    "upright_yaws_deg": [0.0, 60.0]}
_LEGS = tuple(tuple(float(v) for v in a) for a in tetrapod_leg_directions())

register(ClassSpec(
    name="reef_ring", build=_build_ring, symmetry_order=SYMMETRY_CONTINUOUS, colour="#0072B2",
    arrangement="stack", layers=2,
    params={
        "height_m": {**_POS, "default": 0.75},
        "outer_diameter_m": {**_POS, "default": 2.68},
        "outer_wall_m": {**_POS, "default": 0.09},
        "inner_wall_m": {**_POS, "default": 0.06},
        "gap_m": {**_POS, "default": 0.25, "description": "radial gap between the two walls (m)"},
        "outer_holes": {"type": "integer", "minimum": 0, "default": 8},
        "outer_hole_diameter_m": {**_POS, "default": 0.25},
        "inner_holes": {"type": "integer", "minimum": 0, "default": 6},
        "inner_hole_diameter_m": {**_POS, "default": 0.20},
        "n_ribs": {"type": "integer", "minimum": 1, "default": 4, "description": "radial ribs joining the walls"},
        "rib_m": {**_POS, "default": 0.06, "description": "rib thickness (m)"},
    }))
register(ClassSpec(
    name="reef_cone", build=_build_cone, symmetry_order=SYMMETRY_CONTINUOUS, colour="#D55E00",
    arrangement="cluster",
    params={
        "height_m": {**_POS, "default": 1.37},
        "base_diameter_m": {**_POS, "default": 2.0},
        "top_diameter_m": {**_POS, "default": 0.5, "description": "diameter of the top opening (outer, m)"},
        "wall_m": {**_POS, "default": 0.15, "description": "wall thickness normal to the slant surface (m)"},
        "n_holes": {"type": "integer", "minimum": 0, "default": 30},
        "hole_diameter_m": {"type": "array", "items": _POS, "minItems": 2, "maxItems": 2, "default": [0.10, 0.25],
                            "description": "range of hole diameters (m), drawn uniformly"},
    }))
register(ClassSpec(
    name="tetrapod_b", build=_build_tetrapod("tetrapod_b"), symmetry_order=3, colour="#009E73",
    arrangement="spaced", up_axes=_LEGS, tumble=_TETRAPOD_TUMBLE, params=_tetrapod_params(2.08, 6000)))
register(ClassSpec(
    name="tetrapod_s", build=_build_tetrapod("tetrapod_s"), symmetry_order=3, colour="#CC79A7",
    arrangement="pile", layers=3, up_axes=_LEGS, tumble=_TETRAPOD_TUMBLE, params=_tetrapod_params(1.42, 2000)))
