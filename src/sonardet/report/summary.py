"""One-page Markdown summary of a run (headline tables, figure links, config and machine)."""

from __future__ import annotations

import os
import platform
from importlib import metadata
from pathlib import Path

import pandas as pd

from ..determinism import cpu_flags, describe as describe_pinned
from ..io.atomic import atomic_write_text
from .tables import markdown_table

_PACKAGES = (("numpy", ("numpy",)), ("torch", ("torch",)), ("open3d", ("open3d-cpu", "open3d")),
             ("trimesh", ("trimesh",)), ("mujoco", ("mujoco",)), ("pandas", ("pandas",)),
             ("matplotlib", ("matplotlib",)), ("snakemake", ("snakemake",)))


def _version(dists) -> str | None:
    for d in dists:
        try:
            return metadata.version(d)
        except metadata.PackageNotFoundError:
            continue
    return None


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def vector_isa(flags: set[str]) -> str:
    """The widest x86 vector extension among the CPU's feature `flags` ('AVX-512', 'AVX2' with FMA,
    'AVX', 'SSE4.2'), or 'none known' (another architecture, or flags not readable). Outputs are
    byte-stable only between machines of the same extension (README, reproducibility)."""
    if "avx512f" in flags:
        return "AVX-512"
    if {"avx2", "fma"} <= flags:
        return "AVX2"
    for flag, name in (("avx", "AVX"), ("sse4_2", "SSE4.2")):
        if flag in flags:
            return name
    return "none known"


def _ram_gb() -> float | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        return None


def machine_info() -> dict:
    """The machine a run is on: cpu_cores (usable by this process), cpu_model, cpu_vector_isa (its
    widest vector extension), numerical_environment (the pinned thread counts and instruction-set
    paths, `sonardet.determinism`), ram_gb (GiB), os, python, and versions of the main libraries
    (None when not installed; read from package metadata, nothing is imported)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count()
    ram = _ram_gb()
    return {
        "cpu_cores": cores,
        "cpu_model": _cpu_model(),
        "cpu_vector_isa": vector_isa(cpu_flags()),
        "numerical_environment": describe_pinned(),
        "ram_gb": round(ram, 1) if ram is not None else None,
        "os": f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
        "versions": {name: _version(dists) for name, dists in _PACKAGES},
    }


def _kv_lines(d: dict) -> list[str]:
    out = []
    for k, v in d.items():
        if isinstance(v, dict):
            v = ", ".join(f"{kk} {vv}" for kk, vv in v.items() if vv is not None) or "-"
        out.append(f"- **{k}**: {v if v is not None else '-'}")
    return out


def write_results_readme(out_md, tables: dict, figures: dict, config_info: dict, machine_info: dict,
                         title: str = "sonardet results", link_dir=None) -> Path:
    """Write a one-page Markdown summary atomically: the config (e.g. name, hash), the machine (see
    `machine_info()`), each table (name -> DataFrame) as a Markdown table, and each figure (name ->
    PNG path) as an image link relative to `link_dir` (default: the folder of out_md; give the final
    folder when out_md is a staged file). Returns out_md."""
    out_md = Path(out_md)
    lines = [f"# {title}", "", "## Configuration", "", *_kv_lines(config_info), "", "## Machine", "",
             *_kv_lines(machine_info), ""]
    for name, df in tables.items():
        if not isinstance(df, pd.DataFrame):
            raise TypeError(f"table {name!r}: expected a pandas DataFrame, got {type(df).__name__}")
        lines += [f"## {name}", "", markdown_table(df).rstrip("\n"), ""]
    if figures:
        lines += ["## Figures", ""]
        base = Path(link_dir if link_dir is not None else out_md.parent).resolve()
        for name, path in figures.items():
            rel = Path(os.path.relpath(Path(path).resolve(), base)).as_posix()
            lines += [f"### {name}", "", f"![{name}]({rel})", ""]
    atomic_write_text(out_md, "\n".join(lines).rstrip("\n") + "\n")
    return out_md
