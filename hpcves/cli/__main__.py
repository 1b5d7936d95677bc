"""``python -m hpcves.cli``: the ``hpcves`` command line."""
from hpcves.cli import main

if __name__ == "__main__":     # pragma: no cover
    main()
