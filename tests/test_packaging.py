"""pyproject.toml is the single dependency list; environment.yml must mirror it; scripts/setup.sh picks
the torch build."""

import functools
import http.server
import os
import re
import socket
import subprocess
import sys
import threading
import tomllib

import pytest
import yaml

from conftest import REPO


def _norm(spec: str) -> str:
    return re.sub(r"\s+", "", spec).lower()


def test_environment_yml_mirrors_pyproject():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    extras = [s for group in project["optional-dependencies"].values() for s in group]
    wanted = {_norm(s) for s in project["dependencies"] + extras}
    env = yaml.safe_load((REPO / "environment.yml").read_text())
    pip = next(d["pip"] for d in env["dependencies"] if isinstance(d, dict) and "pip" in d)
    listed = {_norm(s) for s in pip if not s.startswith("torch==")}
    # torch: pyproject gives the range, environment.yml the pinned CPU build inside it.
    torch_range = next(s for s in wanted if s.startswith("torch"))
    wanted.discard(torch_range)
    pin = next(s for s in pip if s.startswith("torch=="))
    from packaging.specifiers import SpecifierSet

    assert pin.split("==")[1] in SpecifierSet(torch_range[len("torch"):]), (pin, torch_range)
    assert listed == wanted, (
        f"environment.yml and pyproject.toml differ: only in pyproject {sorted(wanted - listed)}, "
        f"only in environment.yml {sorted(listed - wanted)}"
    )


def test_torch_pinned_in_install_steps():
    env = yaml.safe_load((REPO / "environment.yml").read_text())
    pip = next(d["pip"] for d in env["dependencies"] if isinstance(d, dict) and "pip" in d)
    assert "torch==2.13.0" in pip
    assert "torch==2.13.0" in (REPO / "scripts" / "setup.sh").read_text()


def test_readme_commands_and_ci_agree():
    readme = (REPO / "README.md").read_text()
    ci = (REPO / ".ci" / "run").read_text()
    assert "make run" in readme and "make test" in readme
    assert "make test" in ci


def test_setup_installs_every_extra():
    """setup.sh installs the extras environment.yml lists (test, cluster): the same environment."""
    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    m = re.search(r'-e "\.\[([\w,]+)\]"', (REPO / "scripts" / "setup.sh").read_text())
    assert m and set(m.group(1).split(",")) == set(extras)


def _torch_plan(**env) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(REPO / "scripts" / "setup.sh"), "--print-torch-plan"],
                          env={**{k: v for k, v in os.environ.items() if k not in ("SONARDET_TORCH", "TORCH_INDEX_URL")},
                               "PYTHON": sys.executable, **env}, capture_output=True, text=True,
                          timeout=60)


@pytest.fixture
def local_index(tmp_path):
    """A PyPI-style simple index with a torch page, served on 127.0.0.1 (a reachable PyTorch index)."""
    (tmp_path / "torch").mkdir()
    (tmp_path / "torch" / "index.html").write_text("<html><body></body></html>")
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(tmp_path))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_torch_from_the_chosen_index_when_reachable(local_index):
    proc = _torch_plan(TORCH_INDEX_URL=local_index)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == f"index: {local_index}"


def test_torch_falls_back_to_the_default_index_with_a_note():
    url = f"http://127.0.0.1:{_closed_port()}/whl/cpu"
    proc = _torch_plan(TORCH_INDEX_URL=url)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == "index: pip-default"
    assert f"note: {url} cannot be reached" in proc.stdout and "CUDA build" in proc.stdout


def test_torch_build_choices():
    default = _torch_plan(SONARDET_TORCH="default")
    assert default.stdout.splitlines()[-1] == "index: pip-default" and "note" not in default.stdout
    # The CPU build by default and a CUDA build on request, from PyTorch's index (here reachable or not).
    assert "download.pytorch.org/whl/cpu" in _torch_plan().stdout
    assert "download.pytorch.org/whl/cu128" in _torch_plan(SONARDET_TORCH="cu128").stdout
    bad = _torch_plan(SONARDET_TORCH="gpu")
    assert bad.returncode == 2 and "SONARDET_TORCH=gpu" in bad.stderr
