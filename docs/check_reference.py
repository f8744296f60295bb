"""Check the built site: every public name and CLI option documented, every example's figure shown.

Usage: ``python docs/check_reference.py docs/_build/html`` after ``sphinx-build``. The public
names are ``symplid.__all__``, the namespaces it names and their ``__all__``
(``symplid_api.public_names``, the generator's own list); the entries are read from the
site's ``objects.inv``. Exit code 1, with the missing names listed, if any is missing.
"""

from __future__ import annotations

import sys
from pathlib import Path

from sphinx.util.inventory import InventoryFile

sys.path.insert(0, str(Path(__file__).resolve().parent / "_ext"))
from symplid_api import public_names


def documented(html: Path) -> set[str]:
    """The Python objects listed in the built site's inventory."""
    with open(html / "objects.inv", "rb") as f:
        inventory = InventoryFile.load(f, "", lambda base, uri: uri)
    return {name for kind, entries in inventory.items() if kind.startswith("py:")
            for name in entries}


def cli_anchors() -> list[str]:
    """The anchor sphinx-click gives every visible option of every command (``--out`` of
    ``symplid fit``: ``cmdoption-symplid-fit-out``), from the click commands themselves."""
    import click

    from symplid.cli import main

    out = []

    def walk(command: click.Command, prog: str) -> None:
        for param in command.params:
            if isinstance(param, click.Option) and not param.hidden:
                out.append(f"cmdoption-{prog}-{param.opts[0].lstrip('-')}")
            elif isinstance(param, click.Argument):
                out.append(f"cmdoption-{prog}-arg-{param.name.upper()}")
        for name, sub in getattr(command, "commands", {}).items():
            walk(sub, f"{prog}-{name}")

    walk(main, "symplid")
    return out


def examples_without_figure(html: Path) -> list[str]:
    """Examples whose gallery page shows no figure of their own (or has no page)."""
    root = Path(__file__).resolve().parents[1] / "examples"
    out = []
    for script in sorted(root.glob("*.py")):
        page = html / "auto_examples" / f"{script.stem}.html"
        text = page.read_text(encoding="utf-8") if page.is_file() else ""
        if f"sphx_glr_{script.stem}_0" not in text:
            out.append(script.name)
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python docs/check_reference.py BUILT_HTML_FOLDER", file=sys.stderr)
        return 2
    html = Path(argv[0])
    if not (html / "objects.inv").is_file():
        print(f"{html}: no objects.inv (build the site first)", file=sys.stderr)
        return 2
    missing = sorted(set(public_names()) - documented(html))
    for name in missing:
        print(f"no reference entry: {name}", file=sys.stderr)
    print(f"{len(public_names()) - len(missing)} of {len(public_names())} public names have a "
          "reference entry")
    cli = (html / "reference" / "cli.html").read_text(encoding="utf-8")
    absent = [a for a in cli_anchors() if f'id="{a}"' not in cli]
    for anchor in absent:
        print(f"not in the CLI reference: {anchor}", file=sys.stderr)
    print(f"{len(cli_anchors()) - len(absent)} of {len(cli_anchors())} CLI options and arguments "
          "are in the CLI reference")
    bare = examples_without_figure(html)
    for name in bare:
        print(f"example without a figure on its page: {name}", file=sys.stderr)
    return 1 if missing or absent or bare else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
