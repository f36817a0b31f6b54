"""A notebook-style tour of the nerfsv package on a small world it builds first (a 16×16 monolith
dataset and a NeRF trained for 20 seconds): each cell is one call, printed as a notebook would.

    python python/examples/walkthrough.py [WORKDIR]

It needs the `nerfsv` binary only for the dataset (`nerfsv scene`; NERFSV_BIN or
target/release/nerfsv), and Ray for the last cell.
"""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import nerfsv

work = Path(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp(prefix="nerfsv-"))
binary = os.environ.get("NERFSV_BIN", str(Path(__file__).resolve().parents[2] / "target" / "release" / "nerfsv"))

# %% A dataset: the monolith scene rendered to 16×16 Blender-format views.
subprocess.run([binary, "scene", "--scene", "monolith", "--out", str(work / "ds"), "--width", "16", "--height", "16",
                "--train", "12", "--val", "1", "--test", "2"], check=True)
data = nerfsv.load_dataset(work / "ds", "test")
print("images", data["images"].shape, data["images"].dtype, "poses", data["poses"].shape)

# %% Train a NeRF for 20 s with a progress callback.
(work / "nerf.toml").write_text("[nerf]\naabb_min = [-1.0, -1.0, -1.0]\naabb_max = [1.0, 1.0, 1.0]\n")
last = {}
model = nerfsv.train(work / "ds", work / "nerf", seconds=20, config=work / "nerf.toml", progress=last.update)
print(f"trained {last['step']} steps, batch PSNR {last['psnr']:.1f} dB -> {model.path}")

# %% Render a test view, and compare it with the image.
rgb, depth, opacity = model.render(data["poses"][0], 16, 16, tuple(data["intrinsics"][0]))
truth = data["images"][0][..., :3] * data["images"][0][..., 3:] + (1 - data["images"][0][..., 3:])
print(f"PSNR of test view 0: {-10 * np.log10(np.mean((rgb - truth) ** 2)):.1f} dB, mean depth {depth[opacity > 0.5].mean():.2f} m")

# %% Density along a vertical line through the monolith, and the collision fields.
z = np.linspace(-0.5, 1.0, 7, dtype=np.float32)
print("sigma", np.round(model.density(np.stack([np.zeros_like(z), np.zeros_like(z), z], 1)), 1))
gt = nerfsv.ground_truth_field("monolith")
mine = model.collision_field("monolith")
print("fields", gt["values"].shape, "cell", gt["cell"], "nodes where the signs differ:",
      int(np.sum(np.sign(gt["values"]) != np.sign(mine["values"]))))

# %% The paper's uncertainty of the test image: GA and BLA.
for method in ["ga", "bla"]:
    print(method, nerfsv.uncertainty(model, method, data["poses"][0], 16, 16, tuple(data["intrinsics"][0]), data["images"][0]))

# %% Fly the drone once with disturbances from the prior, in ground-truth sim, truth estimator.
flight = nerfsv.fly(model.path, world="gt", estimator="truth", scene="monolith", random_seed=1)
print("collided", flight["figures"]["collided"], "min clearance", np.nanmin(flight["clearance"]))

# %% A Monte Carlo stress test of 20 rollouts, then the same on a local Ray.
(work / "study.toml").write_text("[sim.vision]\npixels = 16\n[validation.monte_carlo]\nrollouts = 20\n")
one = nerfsv.stress(model.path, work / "mc", sampler="mc", estimator="truth", config=work / "study.toml", scene="monolith")
s = one["samplers"][0]
print(f"one process: P(fail) {s['p_fail']:.2f}, 95 % [{s['p_fail_interval'][0]:.2f}, {s['p_fail_interval'][1]:.2f}]")
try:
    from nerfsv import distributed
    ray_figures = distributed.stress(model.path, work / "mc_ray", sampler="mc", estimator="truth",
                                     config=work / "study.toml", scene="monolith", num_cpus=2)
    same = (work / "mc" / "rollouts.csv").read_bytes() == (work / "mc_ray" / "rollouts.csv").read_bytes()
    print("on Ray: rollouts.csv identical:", same)
except ImportError:
    print("Ray is not installed: pip install 'nerfsv[distributed]'")
