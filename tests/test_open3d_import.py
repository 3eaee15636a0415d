"""Open3D imported without its plotly/dash viewer, which loads on first use (sonardet._open3d_import)."""

import os
import subprocess
import sys
from pathlib import Path

SRC = str(Path(__file__).resolve().parents[1] / "src")

CHECK = """
import sys
import numpy as np
import sonardet
import open3d as o3d
print("dash after import:", "dash" in sys.modules)
pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).random((10, 3))))
fig = o3d.visualization.get_plotly_fig([pc])
print("figure:", type(fig).__name__, len(fig.data))
print("dash after use:", "dash" in sys.modules)
print("package attribute callable:", callable(o3d.visualization.draw_plotly))
mod = sys.modules["open3d.visualization.draw_plotly"]
print("real module:", not getattr(mod, "__sonardet_stand_in__", False), callable(mod.get_point_object))
"""


def _run(env_extra=None):
    env = {k: v for k, v in os.environ.items() if k != "SONARDET_EAGER_OPEN3D"}
    env.update(PYTHONPATH=SRC, **(env_extra or {}))
    out = subprocess.run([sys.executable, "-c", CHECK], env=env, capture_output=True, text=True, check=True)
    return out.stdout.splitlines()


def test_viewer_loads_on_first_use_and_works():
    lines = _run()
    assert lines[0] == "dash after import: False"
    assert lines[1] == "figure: Figure 1"
    assert lines[2] == "dash after use: True"
    assert lines[3] == "package attribute callable: True"
    assert lines[4] == "real module: True True"


def test_eager_import_switch():
    lines = _run({"SONARDET_EAGER_OPEN3D": "1"})
    assert lines[0] == "dash after import: True"
    assert lines[1] == "figure: Figure 1"
