"""Glue for the thin Snakemake scripts: plugins, logging to the rule's log file, error reporting, a
job's method and resources, and its exact CPU record (`sonardet.usage`).

Takes the `snakemake` object duck-typed, so the library imports nothing from Snakemake.
"""

from __future__ import annotations

import gc
import json
import logging
import sys
import time
import traceback
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from .determinism import describe
from .io.atomic import atomic_write_text
from .plugins import load_plugins
from .usage import compilations_note, job_cpu_seconds, job_usage, numba_compilations, usage_path

if TYPE_CHECKING:
    from .methods import Method, Resources


@contextmanager
def rule_logging(smk, name: str):
    """Send `logging` output of the library to the rule's log file (and stderr); log the exception
    and re-raise it on failure, so Snakemake reports the job as failed and removes its outputs."""
    handlers = [logging.StreamHandler(sys.stderr)]
    if getattr(smk, "log", None):
        handlers.append(logging.FileHandler(smk.log[0], mode="w"))
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s: %(message)s",
                        handlers=handlers, force=True)
    log = logging.getLogger(f"sonardet.{name}")
    log.info("numerical environment (sonardet.determinism): %s", describe())
    t0, startup_cpu_s = time.perf_counter(), job_cpu_seconds()
    try:
        yield log
    except Exception:
        log.error("failed:\n%s", traceback.format_exc())
        raise
    jit = numba_compilations()
    usage = job_usage(_threads(smk), startup_cpu_s, jit)
    note = compilations_note(jit)
    log.info("done in %.2f s (the job's process: %.2f s of CPU since it started, %.2f s of it before the "
             "job's work: interpreter, imports)%s", time.perf_counter() - t0, usage["cpu_s"], startup_cpu_s,
             f"; {note}" if note else "")
    if getattr(smk, "log", None):
        atomic_write_text(usage_path(smk.log[0]), json.dumps(usage) + "\n")  # exact CPU (sonardet.usage)
    if is_script_process(smk):
        # The process ends with the job: the interpreter's last garbage collection would walk every
        # object the imports made (PyTorch's, Open3D's) to free nothing the job needs (timed by
        # `benchmarks/job_startup.py --exit`). Frozen objects are left out of it; everything else of
        # an exit (atexit handlers, file closing, thread joins) runs as before.
        gc.freeze()


def is_script_process(smk) -> bool:
    """Whether this process is the job's own script process: Snakemake ran the rule's script as
    ``__main__`` with `smk` as its global ``snakemake`` (not a test or a library calling in)."""
    main = sys.modules.get("__main__")
    return main is not None and getattr(main, "snakemake", None) is smk


def _threads(smk) -> int:
    return int(getattr(smk, "threads", 1) or 1)


@contextmanager
def job(smk, name: str):
    """One workflow job: the config's plugins imported (they may register the job's method or
    classes), then :func:`rule_logging`."""
    with rule_logging(smk, name) as log:
        load_plugins((getattr(smk, "config", None) or {}).get("plugins") or [])
        yield log


def job_method(smk) -> Method:
    """The Method a job runs (the rule's `params.method`)."""
    from .methods import Method  # here, not at the top: most jobs run no method, and the registry is heavy

    return Method.from_dict(smk.params.method)


def job_resources(smk, method: Method | None = None) -> Resources:
    """A job's Resources from its named inputs: `meta` (object JSONs, meshes beside them) -> object
    models, `templates` -> template scans, `model` -> the trained model file (in a job of several
    trained methods `model_{method}`, that of `method`); threads from the job."""
    from .io.templates import read_templates
    from .methods import Resources
    from .objects import read_object

    inp = smk.input
    names = set(inp.keys()) if hasattr(inp, "keys") else set()
    objects = {Path(p).stem: read_object(p) for p in inp.meta} if "meta" in names else None
    templates = {Path(p).stem: read_templates(p) for p in inp.templates} if "templates" in names else None
    model = Path(inp.model) if "model" in names else None
    if method is not None and f"model_{method.name}" in names:
        model = Path(getattr(inp, f"model_{method.name}"))
    device = (method.settings.get("device", "auto") if method is not None else "auto")
    return Resources(objects=objects, templates=templates, model_path=model, device=device,
                     threads=_threads(smk))
