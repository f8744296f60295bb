"""The gallery's glue: each example writes its figures into a folder; they are shown on its page.

The examples save figures with ``Figure.savefig`` (no pyplot), so matplotlib's scraper sees
none. :func:`reset_argv` gives every example an output folder under ``docs/_build`` and
:func:`png_scraper` copies the PNG files it wrote there onto the example's page.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from sphinx_gallery.scrapers import figure_rst

OUT = Path(__file__).resolve().parents[1] / "_build" / "examples-out"
_shown: set[Path] = set()


def reset_argv(gallery_conf: dict[str, Any], script_vars: dict[str, Any]) -> list[str]:
    """The command-line arguments of an example: its output folder (emptied first)."""
    folder = OUT / Path(script_vars["src_file"]).stem
    shutil.rmtree(folder, ignore_errors=True)
    return [str(folder)]


def png_scraper(block: Any, block_vars: dict[str, Any], gallery_conf: dict[str, Any]) -> str:
    """Copy the PNG files the example has written (not yet shown) into the gallery's images."""
    folder = OUT / Path(block_vars["src_file"]).stem
    # the example's own figures sit in its folder; those of runs it made (reports) below it
    figures = sorted(folder.glob("*.png")) or sorted(folder.rglob("*.png"))
    new = [p for p in figures if p not in _shown]
    targets = []
    for png, target in zip(new, block_vars["image_path_iterator"], strict=False):
        shutil.copyfile(png, target)
        _shown.add(png)
        targets.append(target)
    return figure_rst(targets, gallery_conf["src_dir"]) if targets else ""
