"""Shared helper of the workflow's scripts (like the scripts/common module of the snakemake-workflows
exemplars): makes the library importable without an install (e.g. in a rule's conda env), imports
the config's plugins, and gives each job its logging and its method's resources.

Every script starts with ``from common import job`` and runs inside ``with job(snakemake, name) as log``.
"""

import os
import sys

_SRC = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "src"))
if sys.path[0] != _SRC:  # first, before an installed copy (e.g. an editable install of another checkout)
    sys.path.insert(0, _SRC)

from sonardet.workflow import job, job_method, job_resources  # noqa: E402

__all__ = ["job", "job_method", "job_resources"]
