"""The config JSON schema: the packaged `data/schema.yaml` completed from the registries.

The YAML documents every key that does not depend on which classes or methods are registered. The
parts that do are filled in here: the class names of `scenes.class_mix`, each class's
`objects.{cls}` section (from its ClassSpec's parameters, with defaults and descriptions), the
default class mix and the layers of stacked or piled classes (`scenes.pile_layers`); the keys of
the sensor realism profile (`sensor.realism`) and of the scene realism (`scenes.realism`) come
from the sensor effects registry (sonardet.sim.effects).
"""

from __future__ import annotations

import copy
from importlib import resources

import yaml

from ..objects import classes
from ..sim.effects import realism_schema

__all__ = ["read_schema"]


def _packaged() -> dict:
    with resources.files("sonardet").joinpath("data/schema.yaml").open("r") as fh:
        return yaml.safe_load(fh)


def read_schema() -> dict:
    """The config JSON schema shipped with the package, completed from the class registry."""
    schema = _packaged()
    props = schema["properties"]
    names = classes.names()
    objects = props["objects"]["properties"]
    for name in names:
        section = classes.get(name).schema()
        # Defaults are filled for the configured classes only (config._complete): a class registered
        # by a plugin must not change the objects section of a config that does not use it.
        section.pop("default")
        objects[name] = section
    scenes = props["scenes"]["properties"]
    scenes["class_mix"]["propertyNames"] = {"enum": names}
    scenes["class_mix"]["default"] = {c: classes.get(c).mix_weight for c in props["classes"]["default"]}
    piled = [c for c in names if classes.get(c).arrangement in ("stack", "pile")]
    scenes["pile_layers"]["properties"] = {c: {"type": "integer", "minimum": 1, "maximum": 4,
                                               "default": classes.get(c).layers} for c in piled}
    scenes["pile_layers"]["default"] = {c: classes.get(c).layers for c in piled}
    props["sensor"]["properties"]["realism"]["properties"] = realism_schema("sensor")
    scenes["realism"]["properties"] = realism_schema("scenes")
    return copy.deepcopy(schema)
