"""pyproject.toml is the single dependency list; environment.yml must mirror it."""

import re
import tomllib

import yaml

from conftest import REPO


def _norm(spec: str) -> str:
    return re.sub(r"\s+", "", spec).lower()


def test_environment_yml_mirrors_pyproject():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    wanted = {_norm(s) for s in project["dependencies"] + project["optional-dependencies"]["test"]}
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
