"""Train a run, kill it at random moments, resume it to the end; is it its twin never killed?

    python scripts/kill_and_resume.py RUN_DIR --twin TWIN_DIR [--kills 2] [--seed 0]
        [--window 60] -- OVERRIDE [OVERRIDE ...]

Starts ``python -m frl.train OVERRIDE... run_dir=RUN_DIR`` in a session of its own and
sends SIGKILL to its whole process group (run, forkserver, workers) after a delay drawn
uniformly from (0, ``--window``) seconds; then resumes it (``resume=auto``: continued, or
started again if killed before its first commit), kills it
again, ``--kills`` times in all, and lets the last session finish. ``TWIN_DIR`` is the
same command's run never killed (train it first). Prints each kill's moment and the
round committed then, each resume's restore time, and ``scripts/same_run.py``'s
comparison. Exit code 0 when the runs are identical.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import signal
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from same_run import differences

from frl import run_directory as rundir

RESTORED = re.compile(r"round (\d+)'s checkpoint restored in ([\d.]+) s")


def session(command: list[str], kill_after_s: float | None, log: Path) -> tuple[int, str]:
    """Run ``command`` in a new session, SIGKILLed as a group after ``kill_after_s``."""
    with log.open("w") as out:
        process = subprocess.Popen(
            command, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
        )
        try:
            process.wait(timeout=kill_after_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    return process.returncode, log.read_text()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--twin", type=Path, required=True)
    parser.add_argument("--kills", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0, help="seed of the kill moments")
    parser.add_argument("--window", type=float, default=60.0, help="seconds")
    argv = sys.argv[1:] if argv is None else argv
    split = argv.index("--") if "--" in argv else len(argv)
    args = parser.parse_args(argv[:split])
    overrides = argv[split + 1 :]
    if args.kills < 1:
        parser.error(f"--kills must be at least 1, got {args.kills}")
    if args.window <= 0:
        parser.error(f"--window must be positive, got {args.window}")
    if rundir.read_results(args.twin) is None:
        parser.error(f"--twin {args.twin} holds no finished run")
    if args.run_dir.exists():
        parser.error(f"{args.run_dir} exists: give a new directory")

    moments = random.Random(args.seed)
    base = [sys.executable, "-m", "frl.train", *overrides, f"run_dir={args.run_dir}"]
    logs = args.run_dir.parent / f"{args.run_dir.name}.sessions"
    logs.mkdir(parents=True, exist_ok=True)
    for kill in range(args.kills + 1):
        last = kill == args.kills
        delay = None if last else moments.uniform(0, args.window)
        # resume=auto: continue the run, or start it again if killed before a commit
        command = base if kill == 0 else [*base, "resume=auto"]
        code, text = session(command, delay, logs / f"session{kill}.log")
        for round_index, seconds in RESTORED.findall(text):
            print(f"session {kill}: round {round_index}'s checkpoint restored in {seconds} s")
        state = rundir.read_state(args.run_dir)
        committed = 0 if state is None else state.completed_rounds
        if not last:
            ended = "killed" if code == -signal.SIGKILL else f"ended first (exit {code})"
            print(f"session {kill}: {ended} at {delay:.1f} s, {committed} round(s) committed")
        elif code != 0:
            print(f"the last session failed (exit {code}); see {logs}")
            return 1
    found = differences(args.twin, args.run_dir)
    for line in found:
        print(line)
    if not found:
        print("identical to the twin never killed: evaluation tables, models, step rewards")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
