"""Kills a run's whole process group at a chosen moment (tests/test_kill_and_resume.py).

Imported at the start of every Python process of a run whose ``PYTHONPATH`` holds this
folder (the run, its forkserver and workers). ``FRL_KILL_AT=POINT:N`` sends SIGKILL to
the process group at the N-th time a process reaches POINT:

- ``step``: a vehicle is about to take a training step (mid-round);
- ``drive``: a vehicle is about to write its drive, its model already written
  (mid-checkpoint-write: the round's directory is half written);
- ``commit``: the roadside unit has written the round's step rewards and is about to
  commit the round in ``state.json``;
- ``restore``: a resumed vehicle is about to replay its simulation;
- ``vehicle``: as ``step``, but ``FRL_KILL_AT=vehicle:N:TASK`` kills the process of the
  vehicle driving TASK alone (a vehicle's host lost, the roadside unit still up).
"""

import os
import sys

_KILL_AT = os.environ.get("FRL_KILL_AT")
# Ray's own Python processes (Flower's simulation runtime) run none of these points, and
# importing frl into each of them slows Ray's start past its timeouts.
_IN_RAY = "ray" in os.path.normpath(sys.argv[0] if sys.argv else "").split(os.sep)

if _KILL_AT and not _IN_RAY:
    import signal

    import frl.envs.intersection
    import frl.federation.client
    import frl.run_directory

    _point, _count, *_task = _KILL_AT.split(":")
    _reached = 0

    def _counting(function):
        def reach(*args, **kwargs):
            global _reached
            _reached += 1
            if _reached == int(_count):
                os.killpg(os.getpgid(0), signal.SIGKILL)
            return function(*args, **kwargs)

        return reach

    if _point == "step":
        frl.federation.client.acting_step = _counting(frl.federation.client.acting_step)
    elif _point == "vehicle":
        _step = frl.federation.client.acting_step

        def _step_of_one_vehicle(agent, env, obs, *rest):
            global _reached
            if [env.config.task] == _task:
                _reached += 1
                if _reached == int(_count):
                    os.kill(os.getpid(), signal.SIGKILL)
            return _step(agent, env, obs, *rest)

        frl.federation.client.acting_step = _step_of_one_vehicle
    elif _point == "drive":
        frl.federation.client.write_vehicle_snapshot = _counting(
            frl.federation.client.write_vehicle_snapshot
        )
    elif _point == "commit":
        _write_step_rewards = frl.run_directory.write_step_rewards

        def _commit_next(*args, **kwargs):
            _write_step_rewards(*args, **kwargs)
            _counting(lambda: None)()

        frl.run_directory.write_step_rewards = _commit_next
    elif _point == "restore":
        restore = frl.envs.intersection.IntersectionEnv.restore
        frl.envs.intersection.IntersectionEnv.restore = _counting(restore)
    else:
        raise ValueError(f"FRL_KILL_AT: unknown point {_point!r}")
