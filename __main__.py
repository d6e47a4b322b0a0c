"""``python -m material_structures``: the command-line interface (see ``cli``)."""

import sys

from .cli import main

if __name__ == "__main__":  # not when a spawned worker process (multiprocessing, Dask) imports it
    sys.exit(main())
