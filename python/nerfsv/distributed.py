"""Stress tests with their rollouts fanned out as Ray tasks.

``stress(...)`` is ``nerfsv.stress`` (``nerfsv stress``) whose Monte Carlo and CEM rollouts, and
their replays in the other world, fly as Ray tasks: the driver (this process) draws the
disturbances, refits CEM's proposals, keeps the journal and writes every file; each task flies
a chunk of rollouts on a worker that rebuilt the drone once from a *context* (model, fields'
sources and config as bytes) put in the object store once. Results cross as the bits of their
floats, so the files are byte-identical to a one-process run with the same seed. A task whose
worker dies is retried by Ray (``max_retries``) and gives the same results.

On a laptop::

    python -m nerfsv.distributed --model runs/stonehenge/nerf/checkpoint.safetensors \\
        --sampler mc --out stress_mc

On a cluster: the same with ``--address ray://HEAD:10001`` (or ``auto`` on a node of it).
Subset simulation's chains fly as tasks too: level 0 in one batch, then every chain's next
move together.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
from typing import Any, Dict, Iterator, List, Optional, Sequence, Tuple

from . import _nerfsv
from . import stress as _stress

__all__ = ["stress", "executor", "outputs"]


def outputs(folder) -> Dict[str, bytes]:
    """The files of a stress folder that its config and seed determine, by relative path:
    every file, ``stress.json`` without its timings (``seconds``, ``rollouts_per_second``). Two
    runs of the same study, in one process or on any cluster, give equal dicts."""
    from pathlib import Path

    root = Path(folder)
    files = {}
    for p in sorted(root.rglob("*")):
        if p.is_file():
            b = p.read_bytes()
            if p.name == "stress.json":
                v = json.loads(b)
                v.pop("seconds", None)
                v.pop("rollouts_per_second", None)
                b = json.dumps(v, sort_keys=True).encode()
            files[str(p.relative_to(root))] = b
    return files


def _rollouts(context: bytes, world: str, estimator: str, jobs: List[bytes], threads: int,
              kill_marker: Optional[str]) -> List[bytes]:
    """One Ray task: flies ``jobs`` on this worker (the drone built once per worker)."""
    if kill_marker is not None and not os.path.exists(kill_marker):
        # Tests: the first task to get here dies with its worker process, once.
        with open(kill_marker, "w") as f:
            f.write(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return _nerfsv.run_jobs(context, world, estimator, jobs, threads)


def executor(context_ref: Any, *, chunk: int = 4, threads: int = 1, max_retries: int = 3,
             kill_marker: Optional[str] = None):
    """An executor for ``nerfsv.stress(..., executor=...)`` that flies each batch as Ray tasks
    of ``chunk`` rollouts, on ``threads`` threads each, against the context in the object store
    (``ray.put(nerfsv._nerfsv.stress_context(...))``). Results stream back as tasks finish."""
    import ray

    task = ray.remote(num_cpus=threads, max_retries=max_retries)(_rollouts)

    def run(world: str, estimator: str, jobs: List[bytes]) -> Iterator[Tuple[int, bytes]]:
        starts = {}
        for start in range(0, len(jobs), chunk):
            ref = task.remote(context_ref, world, estimator, jobs[start:start + chunk], threads, kill_marker)
            starts[ref] = start
        pending = list(starts)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                for k, result in enumerate(ray.get(ref)):
                    yield starts[ref] + k, result

    return run


def stress(model, out, *, sampler: str = "cem", world: str = "nerf", estimator: str = "vision",
           replay: bool = False, seed: Optional[int] = None, config=None, scene: str = "stonehenge",
           mesh=None, nerf_field=None, resume: bool = False, address: Optional[str] = None,
           chunk: int = 4, threads: int = 1, max_retries: int = 3, num_cpus: Optional[int] = None,
           overrides: Sequence[str] = (), _kill_marker: Optional[str] = None) -> Dict[str, Any]:
    """``nerfsv.stress`` with the rollouts flown as Ray tasks (see the module docs). Connects to
    the cluster at ``address`` (default: a local Ray, started if none runs) unless this process
    is connected already. Returns ``stress.json``'s figures."""
    import ray

    if not ray.is_initialized():
        # num_cpus sizes a local Ray this call starts; a cluster has its own.
        ray.init(address=address, num_cpus=None if address else num_cpus, include_dashboard=False,
                 log_to_driver=False)
    context = _nerfsv.stress_context(model, seed, config, scene, mesh, nerf_field, list(overrides))
    ref = ray.put(context)
    run = executor(ref, chunk=chunk, threads=threads, max_retries=max_retries, kill_marker=_kill_marker)
    return _stress(model, out, sampler=sampler, world=world, estimator=estimator, replay=replay, seed=seed,
                   config=config, scene=scene, mesh=mesh, nerf_field=nerf_field, resume=resume, executor=run,
                   overrides=overrides)


def main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="python -m nerfsv.distributed",
                                description="nerfsv stress with its rollouts flown as Ray tasks")
    p.add_argument("--model", required=True, help="NeRF checkpoint (checkpoint.safetensors)")
    p.add_argument("--out", default="stress", help="output folder (the files of nerfsv stress)")
    p.add_argument("--sampler", default="cem", choices=["mc", "cem", "subset"])
    p.add_argument("--world", default="nerf", choices=["nerf", "gt"])
    p.add_argument("--estimator", default="vision", choices=["vision", "truth"])
    p.add_argument("--replay", action="store_true", help="replay the search's rollouts in the other world")
    p.add_argument("--seed", type=int, help="run seed (default: the config's stress.seed)")
    p.add_argument("--config", help="run config (TOML); default: the embedded one")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.KEY=VALUE",
                   help="override one key of the run config (repeat for more)")
    p.add_argument("--scene", default="stonehenge", help="built-in ground truth")
    p.add_argument("--mesh", help="a mesh file as the ground truth instead")
    p.add_argument("--nerf-field", help="the NeRF's signed field (default: built from --model)")
    p.add_argument("--resume", action="store_true", help="continue a killed run in --out")
    p.add_argument("--address", help="Ray cluster address (default: a local Ray)")
    p.add_argument("--chunk", type=int, default=4, help="rollouts per Ray task")
    p.add_argument("--threads", type=int, default=1, help="threads (and CPUs reserved) per task")
    a = p.parse_args(argv)
    try:
        figures = stress(a.model, a.out, sampler=a.sampler, world=a.world, estimator=a.estimator,
                         replay=a.replay, seed=a.seed, config=a.config, scene=a.scene, mesh=a.mesh,
                         nerf_field=a.nerf_field, resume=a.resume, address=a.address, chunk=a.chunk,
                         threads=a.threads, overrides=a.set)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    json.dump(figures, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
