"""Sweeps beyond one machine: the Hydra launchers frl's sweeps run on, and each job's cores.

A Hydra multirun (``python -m frl.train -m ...``) hands its jobs to a launcher: Hydra's
basic one runs them one after another in this process; the launchers of the ``cluster``
extra (``pip install -c constraints.txt -e '.[cluster]'``) send each job elsewhere:

- ``submitit_slurm``: one SLURM job per run (``hydra-submitit-launcher``);
- ``submitit_local``: the same submission path on this machine, every job at once, for
  trying a SLURM sweep out before the cluster sees it;
- ``ray``: one Ray task per run, on a Ray cluster (``hydra.launcher.ray.init.address``)
  or a local Ray that runs as many at a time as its CPUs allow (``hydra-ray-launcher``).

Every job is still an ordinary frl run: its vehicles in their own processes, its run
directory where the sweep's preset puts it, ``resume=auto`` skipping what finished. A job
needs one core per vehicle plus one for the roadside unit; :func:`launcher_overrides`
asks the launcher for that many CPUs per job and sets the run's ``cores`` to match, so
that jobs sharing a node do not oversubscribe it. ``frl.side_by_side`` stays the way to
run N jobs at a time on one machine without any extra: ``submitit_local`` starts every
job at once and cannot share the cores out (docs/reproduction.md, "On a cluster").
"""

from __future__ import annotations

import importlib.util

LAUNCHERS: dict[str, str] = {
    "submitit_slurm": "hydra_plugins.hydra_submitit_launcher",
    "submitit_local": "hydra_plugins.hydra_submitit_launcher",
    "ray": "hydra_plugins.hydra_ray_launcher",
}
"""The launchers frl's sweep commands know, and the plugin module each needs."""

PACKAGES = {
    "hydra_plugins.hydra_submitit_launcher": "hydra-submitit-launcher",
    "hydra_plugins.hydra_ray_launcher": "hydra-ray-launcher",
}

PAPER_VEHICLES = 3
"""The paper's fleet: one vehicle per task."""


def cores_per_job(vehicles: int = PAPER_VEHICLES) -> int:
    """A job's CPUs: one per vehicle process and one for the roadside unit."""
    if vehicles < 1:
        raise ValueError(f"a run has at least one vehicle, got {vehicles}")
    return vehicles + 1


def require_launcher(name: str) -> None:
    """Raise ``ValueError`` with the fix when ``name`` is unknown or not installed."""
    if name not in LAUNCHERS:
        raise ValueError(f"unknown launcher {name!r}; choose one of {', '.join(LAUNCHERS)}")
    module = LAUNCHERS[name]
    if importlib.util.find_spec(module) is None:
        raise ValueError(
            f"hydra/launcher={name} needs {PACKAGES[module]}, which is not installed: "
            "pip install -c constraints.txt -e '.[cluster]'"
        )


def launcher_overrides(name: str, cores: int) -> list[str]:
    """The Hydra overrides that run a multirun's jobs on launcher ``name``, each job on
    ``cores`` CPUs: the launcher's request (SLURM's ``cpus_per_task``, Ray's
    ``num_cpus``) and the run's own ``cores``, which splits them over its processes."""
    require_launcher(name)
    if cores < 1:
        raise ValueError(f"cores per job must be at least 1, got {cores}")
    if name == "ray":
        request = f"+hydra.launcher.ray.remote.num_cpus={cores}"
    else:
        request = f"hydra.launcher.cpus_per_task={cores}"
    return [f"hydra/launcher={name}", request, f"cores={cores}"]
