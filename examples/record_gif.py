"""Save one episode of the intersection as an animated GIF.

    python examples/record_gif.py --task left --seed 3 --out outputs/left.gif

The car is driven by the gap-acceptance baseline policy (frl.policies).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from frl.envs import TASKS
from frl.policies import GapAcceptancePolicy
from frl.recording import record_episode


def main() -> None:
    parser = argparse.ArgumentParser(description="Record an intersection episode as a GIF.")
    parser.add_argument("--task", choices=TASKS, default="left")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("outputs/episode.gif"))
    args = parser.parse_args()
    path = record_episode(args.out, task=args.task, seed=args.seed, policy=GapAcceptancePolicy())
    print(f"saved {path}")


if __name__ == "__main__":
    main()
