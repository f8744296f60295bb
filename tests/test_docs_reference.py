"""The generated reference pages against the library they document.

The settings reference (``docs/_ext/symplid_settings.py``) must list every key with its true
default: the rows are read back into a settings table and loaded by the library's own settings
reader, which must give the default ``Settings()``; the keys are compared with those of the
writer of a run's ``settings.toml`` (``settings_to_dict``). The API page
(``docs/_ext/symplid_api.py``) is held to the public surface in ``tests/test_public_surface.py``.
(The built site is checked by ``docs/check_reference.py`` in ``.ci/run``.)
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

pytest.importorskip("sphinx")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "docs" / "_ext"))

import tomllib

from symplid.workflow._settings import settings_from_dict, settings_to_dict
from symplid.workflow._settings_schema import Settings


def _rows() -> list[tuple[str, str, str]]:
    """(key, default, meaning) of every row of the generated settings tables."""
    from symplid_settings import settings_rst

    lines = settings_rst()
    rows = []
    for i, line in enumerate(lines):
        key = re.fullmatch(r"   \* - ``(.+)``", line)
        if key and key.group(1) != "key" and lines[i + 1].startswith("     - ``"):
            default = lines[i + 1][len("     - ``"):-2]
            rows.append((key.group(1), default, lines[i + 3][len("     - "):].strip()))
    return rows


def _flat(d: dict, prefix: str = "") -> set[str]:
    out = set()
    for k, v in d.items():
        if isinstance(v, dict) and v and "family" not in v and "prior" not in v:
            out |= _flat(v, f"{prefix}{k}.")
        else:
            out.add(f"{prefix}{k}")
    return out


def test_every_settings_key_is_documented_once_with_a_meaning():
    rows = _rows()
    keys = [k for k, _, _ in rows]
    assert len(keys) == len(set(keys))
    assert set(keys) == _flat(settings_to_dict(Settings()))
    assert all(meaning for _, _, meaning in rows), [k for k, _, m in rows if not m]


def test_documented_defaults_load_back_to_the_defaults():
    text = []
    sections: dict[str, list[str]] = {}
    for key, default, _ in _rows():
        section, _, name = key.rpartition(".")
        sections.setdefault(section, []).append(f"{name} = {default}")
    text += sections.pop("")
    for section, lines in sections.items():
        text += [f"[{section}]", *lines]
    loaded = settings_from_dict(tomllib.loads("\n".join(text)), "the reference")
    assert loaded == Settings()
