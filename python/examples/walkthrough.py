"""A notebook-style tour of the nerfsv package on a small world it builds first (a 32×32 monolith
dataset and a NeRF trained for 30 seconds): each cell is one call, printed as a notebook would.

    python python/examples/walkthrough.py [WORKDIR]

It needs the `nerfsv` binary for the dataset and the ground truth's field (`nerfsv scene`,
`nerfsv collision`; NERFSV_BIN or target/release/nerfsv), and Ray for the last cell.
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

# %% A dataset: the monolith scene rendered to 32×32 Blender-format views.
subprocess.run([binary, "scene", "--scene", "monolith", "--out", str(work / "ds"), "--width", "32", "--height", "32",
                "--train", "30", "--val", "1", "--test", "2"], check=True, capture_output=True)
data = nerfsv.load_dataset(work / "ds", "test")
print("images", data["images"].shape, data["images"].dtype, "poses", data["poses"].shape)

# %% Train a NeRF for 30 s with a progress callback.
last = {}
model = nerfsv.train(work / "ds", work / "nerf", seconds=30, progress=last.update)
print(f"trained {last['step']} steps, batch PSNR {last['psnr']:.1f} dB -> {model.path}")

# %% Render a test view, and compare it with the image.
rgb, depth, opacity = model.render(data["poses"][0], 32, 32, tuple(data["intrinsics"][0]))
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
    print(method, nerfsv.uncertainty(model, method, data["poses"][0], 32, 32, tuple(data["intrinsics"][0]), data["images"][0]))

# %% Fly the drone once with disturbances from the prior, in ground-truth sim, truth estimator. The
# planner needs a map it can trust: a 30-second NeRF's field is too rough near the start, so the
# tour plans on the ground truth's field (`nerfsv collision`), passed where the NeRF's would go.
subprocess.run([binary, "collision", "--scene", "monolith", "--out", str(work / "gt.safetensors")], check=True,
               capture_output=True)
flight = nerfsv.fly(model.path, world="gt", estimator="truth", scene="monolith", random_seed=1,
                    nerf_field=work / "gt.safetensors")
print("collided", flight["figures"]["collided"], "min clearance", np.nanmin(flight["clearance"]))

# %% A Monte Carlo stress test of 20 rollouts, then the same on a local Ray.
(work / "study.toml").write_text("[sim.vision]\npixels = 16\n[stress.monte_carlo]\nrollouts = 20\n")
one = nerfsv.stress(model.path, work / "mc", sampler="mc", estimator="truth", config=work / "study.toml",
                    scene="monolith", nerf_field=work / "gt.safetensors")
s = one["samplers"][0]
print(f"one process: P(fail) {s['p_fail']:.2f}, 95 % [{s['p_fail_interval'][0]:.2f}, {s['p_fail_interval'][1]:.2f}]")
try:
    from nerfsv import distributed
    ray_figures = distributed.stress(model.path, work / "mc_ray", sampler="mc", estimator="truth",
                                     config=work / "study.toml", scene="monolith",
                                     nerf_field=work / "gt.safetensors", num_cpus=2)
    print("on Ray: the same files:", distributed.outputs(work / "mc") == distributed.outputs(work / "mc_ray"))
except ImportError:
    print("Ray is not installed: pip install 'nerfsv[distributed]'")
