"""The ``## Parameters`` tables of ``docs/modules/*.md``, generated from the algorithms' docstrings.

A thin command line over :mod:`sppo_sb3.docs_tables`: it checks that each page's table (between the
``<!-- parameters: ... -->`` and ``<!-- /parameters -->`` lines) matches the class docstring and signature, and
exits with status 1 where one does not; ``--write`` rewrites the stale tables in place.

Example::

    python scripts/parameter_tables.py           # check
    python scripts/parameter_tables.py --write   # regenerate after editing a docstring
"""

from __future__ import annotations

import sys
from pathlib import Path

from sppo_sb3.docs_tables import main

if __name__ == "__main__":
    sys.exit(main(docs_dir=Path(__file__).resolve().parents[1] / "docs" / "modules"))
