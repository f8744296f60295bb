"""``python -m symplid.cli``: the ``symplid`` command."""

from symplid.cli import main

main()
