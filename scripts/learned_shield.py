"""A learned ``Q̄`` on the Point Robot scored as a shield uses it: ``sppo_lab.learned_shield`` (``--help``).

python scripts/learned_shield.py                 # the figures of docs/results/appendix_learned_shields.md
python scripts/learned_shield.py --steps 3000 --hold 1   # a warm-up's uniform walk: almost no danger to learn
"""

from __future__ import annotations

import sys

from sppo_lab.learned_shield import main

if __name__ == "__main__":
    sys.exit(main())
