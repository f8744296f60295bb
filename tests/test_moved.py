"""The old paths of the private modules: ``symplid.model.priors`` still imports, for one
version, as the very module ``symplid.model._priors`` is, with a ``MovedModuleWarning``.

Checked against the files of the package: every private module whose public-looking name no
file provides is reachable by that name, and a name that was never a module is not."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from symplid._moved import MovedModuleWarning

SRC = Path(__file__).resolve().parents[1] / "src"


def _moved() -> list[tuple[str, str]]:
    """(old path, new path) for every ``_name.py`` of a package without ``name.py`` beside it."""
    out = []
    for path in sorted((SRC / "symplid").rglob("_*.py")):
        if path.name.startswith("__") or (path.parent / path.name[1:]).exists():
            continue
        package = ".".join(path.parent.relative_to(SRC).parts)
        if "_ukf_kernel" in path.name:
            continue
        out.append((f"{package}.{path.stem[1:]}", f"{package}.{path.stem}"))
    return out


def test_the_old_path_is_the_private_module_with_a_warning():
    new = importlib.import_module("symplid.model._priors")
    sys.modules.pop("symplid.model.priors", None)
    moved = r"symplid\.model\.priors .* symplid\.model\._priors"
    with pytest.warns(MovedModuleWarning, match=moved):
        old = importlib.import_module("symplid.model.priors")
    assert old is new
    assert old.__name__ == "symplid.model._priors"  # the module itself, not a copy
    with pytest.warns(MovedModuleWarning):
        sys.modules.pop("symplid.dynamics.integrators", None)
        from symplid.dynamics.integrators import INTEGRATORS
    assert INTEGRATORS is importlib.import_module("symplid").INTEGRATORS


def test_every_moved_module_is_found_in_a_fresh_interpreter():
    """In a fresh process (nothing imported yet), each old path resolves to its new module."""
    pairs = _moved()
    assert ("symplid.workflow.fit", "symplid.workflow._fit") in pairs
    assert ("symplid.registry", "symplid._registry") in pairs
    code = (
        "import importlib, warnings, sys\n"
        "warnings.simplefilter('ignore')\n"
        f"pairs = {pairs!r}\n"
        "imp = importlib.import_module\n"
        "bad = [o for o, n in pairs if imp(o) is not imp(n)]\n"
        "print(len(pairs), bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"}, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split(maxsplit=1) == [str(len(pairs)), "[]\n"]


@pytest.mark.parametrize("name", ["symplid.model.nothing", "symplid.inference.map.nothing",
                                  "symplid.nothing"])
def test_a_name_that_was_never_a_module_is_still_missing(name):
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(name)


def test_public_and_private_paths_import_without_a_warning(recwarn):
    for name in ["symplid.priors", "symplid.io", "symplid.inference.map", "symplid.model._data"]:
        importlib.import_module(name)
    assert not [w for w in recwarn if issubclass(w.category, MovedModuleWarning)]
