"""A fifth object class, defined only here and registered from the test config (key `plugins`), to
show that a class needs one spec and a config line: a solid concrete cube (default edge 1.2 m).

    plugins: [tests/plugins/cube_class.py]
    classes: [reef_ring, reef_cone, tetrapod_b, tetrapod_s, concrete_cube]
"""

from __future__ import annotations

import numpy as np
import trimesh

from sonardet.objects import ClassSpec, ObjectModel, classes


def build_cube(p: dict, objects_cfg: dict) -> ObjectModel:
    """A cube of edge `edge_m` (m) resting on a face, canonical frame (base centre at the origin)."""
    edge = float(p["edge_m"])
    mesh = trimesh.creation.box(extents=[edge, edge, edge])
    mesh.apply_translation([0.0, 0.0, 0.5 * edge])
    return ObjectModel("concrete_cube", mesh, [np.asarray(mesh.vertices)], edge ** 3, 4, {"edge_m": edge})


FACES = ((0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0))

classes.register(ClassSpec(
    name="concrete_cube", build=build_cube, symmetry_order=4, colour="#E69F00", arrangement="scatter",
    up_axes=FACES, tumble={"mode": "tilts", "tilts_deg": [], "azimuths_n": 1, "yaws_deg": [0.0],
                           "upright_yaws_deg": [0.0]},
    params={"edge_m": {"type": "number", "exclusiveMinimum": 0, "default": 1.2, "description": "edge length (m)"}}))
