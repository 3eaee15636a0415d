"""sonardet: training-free and learned 3D object detection in multibeam echosounder point clouds."""

__version__ = "0.1.0"

#: Version of every JSON artifact this package writes; readers reject other versions.
SCHEMA_VERSION = 1
