"""Rollouts per second of a stress test in one process (`nerfsv stress`) and on Ray
(`nerfsv.distributed`), the per-task overhead, the bytes shipped, and a simulated cluster of
several Ray nodes on this machine.

    python python/benches/ray_stress.py RUN_DIR [--sampler mc] [--nodes 4]

RUN_DIR is a finished `nerfsv run` (its model and NeRF field are used; the default config).
Prints one JSON object; BENCHMARKS.md records it with the machine.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BIN = os.environ.get("NERFSV_BIN", str(ROOT / "target" / "release" / "nerfsv"))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("run", type=Path)
    ap.add_argument("--sampler", default="mc")
    ap.add_argument("--nodes", type=int, default=4)
    ap.add_argument("--chunk", type=int, default=4)
    a = ap.parse_args()
    model = a.run / "nerf" / "checkpoint.safetensors"
    field = a.run / "nerf_collision" / "nerf_sdf.safetensors"
    work = Path(tempfile.mkdtemp(prefix="ray-bench-"))
    out = {"sampler": a.sampler, "cpus": os.cpu_count()}

    # One process: the CLI.
    t = time.perf_counter()
    subprocess.run([BIN, "stress", "--model", str(model), "--nerf-field", str(field), "--sampler", a.sampler,
                    "--out", str(work / "cli")], check=True, capture_output=True)
    out["one_process_s"] = time.perf_counter() - t
    rollouts = json.loads((work / "cli" / "stress.json").read_text())["samplers"][0]["rollouts"]
    out["rollouts"] = rollouts

    import ray
    import nerfsv
    from nerfsv import _nerfsv, distributed
    from nerfsv.distributed import outputs as files

    # A local two-CPU Ray (started before the clock: a cluster is up before a study).
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    t = time.perf_counter()
    distributed.stress(model, work / "ray", sampler=a.sampler, nerf_field=field, chunk=a.chunk)
    out["ray_s"] = time.perf_counter() - t
    out["identical"] = files(work / "ray") == files(work / "cli")
    out["one_process_rollouts_per_s"] = rollouts / out["one_process_s"]
    out["ray_rollouts_per_s"] = rollouts / out["ray_s"]
    out["ray_overhead"] = out["ray_s"] / out["one_process_s"] - 1

    # Per-task overhead and bytes: the same jobs flown in this process and as one-job tasks.
    context = _nerfsv.stress_context(model, None, None, "stonehenge", None, str(field))
    ref = ray.put(context)
    out["context_bytes"] = len(context)
    prior_draws = []
    import numpy as np
    rng = np.random.default_rng(0)
    std = np.array([0.01] * 3 + [0.01] * 3 + [0.02] * 3 + [0.02] * 3)  # a mild draw; what is timed is the plumbing
    for i in range(8):
        x = rng.normal(size=(6, 12)) * std
        prior_draws.append(int(i).to_bytes(8, "little") + (12).to_bytes(8, "little") + (72).to_bytes(8, "little")
                           + x.astype("<f8").tobytes())
    out["job_bytes"] = len(prior_draws[0])
    _nerfsv.run_jobs(context, "nerf", "truth", prior_draws[:1], 1)  # build the drone here first
    t = time.perf_counter()
    local = _nerfsv.run_jobs(context, "nerf", "truth", prior_draws, 1)
    local_s = (time.perf_counter() - t) / len(prior_draws)
    task = ray.remote(num_cpus=1)(distributed._rollouts)
    ray.get([task.remote(ref, "nerf", "truth", prior_draws[:1], 1, None) for _ in range(2)])  # warm both workers
    t = time.perf_counter()
    remote = ray.get([task.remote(ref, "nerf", "truth", [j], 1, None) for j in prior_draws])
    remote_s = (time.perf_counter() - t) / len(prior_draws) * 2  # two tasks run at once
    out["result_bytes"] = len(local[0])
    out["identical_results"] = [r[0] for r in remote] == list(local)
    out["truth_rollout_local_s"] = local_s
    out["per_task_overhead_s"] = remote_s - local_s
    ray.shutdown()

    # A simulated cluster: several Ray nodes (raylets) on this machine, one CPU each.
    from ray.cluster_utils import Cluster
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    for _ in range(a.nodes - 1):
        cluster.add_node(num_cpus=1)
    ray.init(address=cluster.address, include_dashboard=False, log_to_driver=False)
    cluster.wait_for_nodes()

    @ray.remote(num_cpus=1)
    def where(i):
        time.sleep(0.2)
        return ray.get_runtime_context().get_node_id()

    nodes = ray.get([where.remote(i) for i in range(4 * a.nodes)])
    out["nodes"] = a.nodes
    out["tasks_per_node"] = sorted(nodes.count(n) for n in set(nodes))
    t = time.perf_counter()
    distributed.stress(model, work / "cluster", sampler=a.sampler, nerf_field=field, chunk=a.chunk)
    out["cluster_s"] = time.perf_counter() - t
    out["cluster_identical"] = files(work / "cluster") == files(work / "cli")
    ray.shutdown()
    cluster.shutdown()
    json.dump(out, sys.stdout, indent=2)
    print()


if __name__ == "__main__":
    main()
