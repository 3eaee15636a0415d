"""sonardet: training-free and learned 3D object detection in multibeam echosounder point clouds."""

__version__ = "0.1.0"

#: Version of every JSON artifact this package writes; readers reject other versions.
SCHEMA_VERSION = 1

# Open3D's plotly/dash viewer is imported when first used, not with Open3D (sonardet._open3d_import).
from ._open3d_import import install as _install_open3d_stand_in  # noqa: E402

_install_open3d_stand_in()
