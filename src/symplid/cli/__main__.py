"""``python -m symplid.cli``: the ``symplid`` command."""

from symplid.cli import main

__all__: list[str] = []

if __name__ == "__main__":
    main()
