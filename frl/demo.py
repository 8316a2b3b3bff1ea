"""A few episodes of the gap-acceptance driver on each task, a summary table and a GIF.

python -m frl.demo [--episodes N] [--seed S] [--traffic paper|dense] [--gif PATH]
"""

from __future__ import annotations

from pathlib import Path

from frl.cli import OneLineParser, seed_value
from frl.envs import TASKS, TRAFFIC_PRESETS, EnvConfig, IntersectionEnv, traffic_preset
from frl.episodes import run_episodes, summarize
from frl.policies import GapAcceptancePolicy
from frl.recording import record_episode

GIF_TASK = "left"


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(prog="python -m frl.demo", description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=5, help="episodes per task")
    parser.add_argument("--seed", type=seed_value, default=0)
    parser.add_argument("--traffic", choices=list(TRAFFIC_PRESETS), default="paper")
    parser.add_argument("--gif", type=Path, default=Path("outputs/demo.gif"))
    args = parser.parse_args(argv)
    if args.episodes <= 0:
        parser.error("--episodes must be positive")

    scenario = traffic_preset(args.traffic)
    print(f"gap-acceptance driver, traffic {args.traffic}")
    print(f"{'task':<9} {'return':>8} {'collisions':>11} {'arrived':>8} {'travel steps':>13}")
    seeds = range(args.seed * 1000, args.seed * 1000 + args.episodes)
    gif_seed = seeds[0]
    for task in TASKS:
        config = EnvConfig(task=task, scenario=scenario)
        env = IntersectionEnv(config)
        try:
            records = run_episodes(env, GapAcceptancePolicy(config), task, seeds)
        finally:
            env.close()
        if task == GIF_TASK:  # show a crossing: the first episode of the table that arrived
            gif_seed = next((s for s, r in zip(seeds, records, strict=True) if r.arrived), gif_seed)
        m = summarize(records)
        collisions = sum(r.collision for r in records)
        arrivals = sum(r.arrived for r in records)
        travel = "-" if m["average_travel_time"] is None else f"{m['average_travel_time']:.1f}"
        print(
            f"{task:<9} {m['average_reward']:>8.2f} {collisions:>5}/{args.episodes:<5} "
            f"{arrivals:>4}/{args.episodes:<3} {travel:>13}"
        )
    config = EnvConfig(scenario=scenario)
    path = record_episode(
        args.gif, task=GIF_TASK, seed=gif_seed, policy=GapAcceptancePolicy(config), config=config
    )
    print(f"saved the {GIF_TASK} turn of seed {gif_seed} as an animation to {path}")


if __name__ == "__main__":
    main()
