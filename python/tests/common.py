"""What the Python tests share: the `nerfsv` binary they build fixtures with (NERFSV_BIN, else
the workspace's target/release/nerfsv), the stress tests' small study, and a tiny world (a
monolith dataset and a 2-step model in a ±1 m box) made with it."""

import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BIN = os.environ.get("NERFSV_BIN", str(ROOT / "target" / "release" / "nerfsv"))

# The stress tests' small study (as tests/stress.rs): 6 steps of the vision drone with 16
# pixels, a wide prior so that some rollouts fail, subset simulation's levels of 20
# (chains of 2, so that its second level flies at the wide prior's failure rate).
STUDY = """[sim.vision]
pixels = 16
iterations = 2
images_per_step = 2
[stress]
seed = 5
[stress.disturbance]
std = [0.08, 0.08, 0.04, 0.04, 0.04, 0.04, 0.08, 0.08, 0.08, 0.04, 0.04, 0.04]
[stress.monte_carlo]
rollouts = 8
[stress.cem]
m = 6
m_elite = 2
k_max = 2
is_samples = 6
[stress.subset]
samples = 20
p0 = 0.5
max_levels = 2
"""


def cli(*args):
    """Runs the binary with `args`; its stdout, or a failed assertion with its stderr."""
    r = subprocess.run([BIN, *map(str, args)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r.stdout


def tiny_world(d: Path, size: int = 8, test: int = 1, field: bool = False) -> dict:
    """In `d`: a `size`×`size` monolith dataset (2 train, 1 val, `test` test views), a 2-step
    model in a ±1 m box, and with `field` the monolith's ground-truth field and the small study's
    config. Returns their paths (`dir`, `ds`, `model`, `nerf_toml`, and `field`, `study`)."""
    ds = d / "ds"
    cli("scene", "--scene", "monolith", "--out", ds, "--width", size, "--height", size, "--train", 2, "--val", 1,
        "--test", test, "--supersample", 1)
    (d / "nerf.toml").write_text("[nerf]\naabb_min = [-1.0, -1.0, -1.0]\naabb_max = [1.0, 1.0, 1.0]\n")
    cli("train", "--data", ds, "--out", d / "nerf", "--steps", 2, "--config", d / "nerf.toml")
    world = {"dir": d, "ds": ds, "model": d / "nerf" / "checkpoint.safetensors", "nerf_toml": d / "nerf.toml"}
    if field:
        cli("collision", "--scene", "monolith", "--out", d / "gt.safetensors")
        (d / "study.toml").write_text(STUDY)
        world.update(field=d / "gt.safetensors", study=d / "study.toml")
    return world
