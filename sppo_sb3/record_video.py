"""``sppo-record-video`` / ``python -m sppo_sb3.record_video``: rl-zoo3's record_video with the package's algorithms.

Every rl-zoo3 flag works unchanged (``--algo sppo --env SafePointCircle-v0 -f logs/ -n 1000 -o videos/``); the
video goes to ``<log folder>/videos`` unless ``-o`` says otherwise. Models are loaded to be watched (no training
buffers, see :mod:`sppo_sb3.enjoy`).
"""

from __future__ import annotations

import runpy
import sys
from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> None:
    """Run rl-zoo3's record_video script with the package's algorithms registered.

    :param argv: command-line arguments (default: ``sys.argv[1:]``).
    """
    from sppo_sb3.zoo import register_algos

    register_algos()
    saved_argv = sys.argv
    sys.argv = [saved_argv[0] if saved_argv else "sppo-record-video", *(sys.argv[1:] if argv is None else argv)]
    try:
        # rl-zoo3's record_video is a script (its code runs under ``if __name__ == "__main__"``)
        runpy.run_module("rl_zoo3.record_video", run_name="__main__")
    finally:
        sys.argv = saved_argv


if __name__ == "__main__":
    main()
