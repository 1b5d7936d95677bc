"""``python -m hpcves``: the same command line as the ``hpcves`` script (cli/)."""
from hpcves.cli import main

if __name__ == "__main__":
    main(prog_name="hpcves")
