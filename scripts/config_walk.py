"""How often the way from the command to the run climbs back up frl's layers.

Runs ``frl.training.train`` (or ``frl.run_opening.open_run``) on a tiny quick run in this
process, with a profile hook that notes every frl function the first time it is called.
Read in that order, as someone following the run from the command would read them, each
function sits in a module of a layer (docs/layout.md, ``tests/test_layering.py``). A
**climb** is a step from one function to the next whose module sits in a higher layer:
the reader went down into a lower layer and has to come back up. Worker processes are
not followed: their code is the run itself, not the way to it.

    python scripts/config_walk.py                 # training.train
    python scripts/config_walk.py --entry open_run --list
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "frl"


def layering() -> Any:
    """The layer table of ``tests/test_layering.py`` (one table, kept by its test)."""
    spec = importlib.util.spec_from_file_location("layering", ROOT / "tests" / "test_layering.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def module_of(filename: str) -> str | None:
    """``frl.x.y`` for a file of the package, None for any other file."""
    path = Path(filename).resolve()
    if PACKAGE not in path.parents:
        return None
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def first_calls(entry: Any, *args: Any) -> list[tuple[str, str]]:
    """``(module, function)`` of every frl function ``entry(*args)`` calls in this
    process, in the order of their first call (``entry`` itself first)."""
    seen: dict[tuple[str, str], None] = {}

    def hook(frame: Any, event: str, _: Any) -> None:
        if event != "call":
            return
        module = module_of(frame.f_code.co_filename)
        if module is not None:
            seen.setdefault((module, frame.f_code.co_qualname), None)

    sys.setprofile(hook)
    try:
        entry(*args)
    finally:
        sys.setprofile(None)
    return list(seen)


def climbs(walk: list[tuple[str, str]], layer_of: Any) -> list[int]:
    """Indices in ``walk`` where the next function's layer is above the one before."""
    layers = [layer_of(module) for module, _ in walk]
    return [i for i in range(1, len(walk)) if layers[i] > layers[i - 1]]


def tiny_config(run_dir: Path) -> Any:
    from hydra import compose, initialize_config_module

    from frl.train_config import register_configs

    register_configs()
    overrides = [
        "+experiment=quick",
        "total_steps=40",
        "interval=20",
        "agent.learning_starts=10",
        "agent.batch_size=8",
        "eval_episodes=0",
        "yardsticks=[]",
        "progress=false",
        f"run_dir={run_dir}",
    ]
    with initialize_config_module(config_module="frl.conf", version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--entry", choices=("train", "open_run"), default="train")
    parser.add_argument("--list", action="store_true", help="print the walk, climbs marked")
    args = parser.parse_args(argv)
    layer_of = layering().layer_of
    with tempfile.TemporaryDirectory() as tmp:
        cfg = tiny_config(Path(tmp) / "run")
        if args.entry == "train":
            from frl.training import train

            walk = first_calls(train, cfg)
        else:
            from frl.run_opening import open_run

            walk = first_calls(open_run, cfg, None)
    up = set(climbs(walk, layer_of))
    if args.list:
        for index, (module, function) in enumerate(walk):
            mark = "^" if index in up else " "
            print(f"{mark} {layer_of(module)} {module}.{function}")
    print(f"{args.entry}: {len(walk)} frl functions, {len(up)} climbs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
