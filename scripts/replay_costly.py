"""Replay a recorded costly episode closed loop, on any machine: does the shield's rule now hold?

A ``ShieldWrapper`` records every episode that pays cost behind it; the train CLI writes the records to
``costly_episodes/`` in the run folder (:mod:`sppo_sb3.shield.records`). This rebuilds the env, resets it from the
recorded randomness and feeds the recorded proposals through the recorded rule (or ``--rule``), one per env step::

    python scripts/replay_costly.py logs/sppo/SafetyPointGoal1-v0_1/costly_episodes/env_0_episode_12.json
    python scripts/replay_costly.py RECORD.json --window   # also print the decisions of the last steps

It prints the recorded and the replayed costly steps and exits 1 where the replay still pays cost.
"""

from __future__ import annotations

import argparse
import sys

import sppo_sb3  # noqa: F401  (registers the tasks and rules)
from sppo_sb3.shield.records import CostlyEpisode
from sppo_sb3.shield.replay import replay


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("record", help="a costly episode's record (JSON)")
    parser.add_argument("--rule", default=None, help="a registered rule's name to replay with (default: the recorded one)")
    parser.add_argument("--window", action="store_true", help="print the recorded decisions before the last costly step")
    args = parser.parse_args()
    record = CostlyEpisode.load(args.record)
    commit = record.provenance.get("commit") or "unknown"
    print(
        f"{record.env_id}, rule {record.rule or record.rule_class} {record.rule_params.get('eta', '')}, episode "
        f"{record.episode}, recorded at commit {commit[:12]} ({record.provenance.get('packages', {}).get('mujoco')} mujoco)"
    )
    if args.window:
        log = record.log
        for t in range(record.window_start, len(log.cost)):
            print(
                f"  env step {t:4d}  proposed {log.proposed[t]}  executed {log.executed[t]}  intervened "
                f"{log.intervened[t]!s:5}  Ā {log.advantage[t]}  cost {log.cost[t]}"
            )
    try:
        result = replay(record, rule=args.rule)
    except ValueError as error:
        print(f"cannot replay: {error}", file=sys.stderr)
        return 2
    print(result.summary())
    return 0 if result.holds else 1


if __name__ == "__main__":
    sys.exit(main())
