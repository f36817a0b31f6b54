"""The Python package against the command line: shapes and dtypes, the same renders and the
same stress files, a distributed run on a local two-CPU Ray equal to `nerfsv stress` byte for
byte (also when a worker dies mid-task), and bad arguments as ValueError with the Rust message.

The fixtures are built on the fly with the `nerfsv` binary (NERFSV_BIN, else the workspace's
target/release/nerfsv): an 8×8 monolith dataset, a 2-step model in a ±1 m box, the monolith's
ground-truth field.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import nerfsv

from common import STUDY, cli, tiny_world


@pytest.fixture(scope="session")
def world(tmp_path_factory):
    return tiny_world(tmp_path_factory.mktemp("world"), field=True)


def stress_files(out: Path):
    from nerfsv.distributed import outputs

    return outputs(out)


def test_dataset_model_and_fields_have_their_shapes_and_dtypes(world, tmp_path):
    data = nerfsv.load_dataset(world["ds"], "train", depth=True)
    assert data["images"].shape == (2, 8, 8, 4) and data["images"].dtype == np.float32
    assert data["poses"].shape == (2, 4, 4) and data["poses"].dtype == np.float32
    assert data["intrinsics"].shape == (2, 4) and data["depths"].shape == (2, 8, 8)
    assert len(data["names"]) == 2

    model = nerfsv.Model.load(world["model"])
    rgb, depth, opacity = model.render(data["poses"][0], 8, 8, tuple(data["intrinsics"][0]))
    assert (rgb.shape, depth.shape, opacity.shape) == ((8, 8, 3), (8, 8), (8, 8))
    assert rgb.dtype == depth.dtype == opacity.dtype == np.float32
    sigma = model.density(np.zeros((5, 3)))  # float64 input is converted
    assert sigma.shape == (5,) and sigma.dtype == np.float32

    gt = nerfsv.ground_truth_field("monolith")
    nx, ny, nz = gt["dims"]
    assert gt["values"].shape == (nz, ny, nx) and gt["values"].dtype == np.float32
    assert len(gt["origin"]) == 3 and gt["cell"] == pytest.approx(1 / 40, rel=1e-3)
    loaded = nerfsv.load_field(world["field"])
    assert np.array_equal(loaded["values"], gt["values"]), "the file nerfsv collision wrote is this field"
    nf = model.collision_field("monolith")
    assert nf["values"].shape == gt["values"].shape and nf["dims"] == gt["dims"]

    for method, key in [("ga", "sigma_d"), ("bla", "normalized_trace")]:
        f = nerfsv.uncertainty(model, method, data["poses"][0], 8, 8, tuple(data["intrinsics"][0]), data["images"][0])
        assert f is None or np.isfinite(f[key]), f
        # The model's own method gives the same figures as a dict too (or None), not JSON text.
        direct = model.uncertainty(method, np.asarray(data["poses"][0], np.float32), 8, 8,
                                   tuple(data["intrinsics"][0]), np.asarray(data["images"][0], np.float32))
        assert direct is None or isinstance(direct, dict), direct
        assert json.dumps(direct, sort_keys=True) == json.dumps(f, sort_keys=True)

    flight = nerfsv.fly(world["model"], world="gt", estimator="truth", config=world["study"], scene="monolith",
                        nerf_field=world["field"], random_seed=3)
    n = len(flight["time"])
    assert flight["position"].shape == (n, 3) and flight["estimate"].shape == (n, 3)
    assert flight["clearance"].shape == (n,) and flight["position"].dtype == np.float64
    assert flight["figures"]["world"] == "gt" and "collided" in flight["figures"]


def test_a_python_render_equals_the_cli_render_bit_for_bit(world, tmp_path):
    cli("render", "--model", world["model"], "--data", world["ds"], "--split", "test", "--out", tmp_path / "cli")
    data = nerfsv.load_dataset(world["ds"], "test")
    model = nerfsv.Model.load(world["model"])
    rgb, depth, opacity = model.render(data["poses"][0], 8, 8, tuple(data["intrinsics"][0]))
    nerfsv.write_png(tmp_path / "py.png", rgb)
    nerfsv.write_depth_png(tmp_path / "py_depth.png", depth, opacity)
    assert (tmp_path / "py.png").read_bytes() == (tmp_path / "cli" / "r_0.png").read_bytes()
    assert (tmp_path / "py_depth.png").read_bytes() == (tmp_path / "cli" / "r_0_depth.png").read_bytes()


def test_the_kernel_width_is_read_at_import_and_changes_no_bit(world, tmp_path):
    # A render in a fresh interpreter at the portable kernels and at the host's widest: the
    # same bytes; an unknown width is refused when the package is imported.
    script = (
        "import sys, nerfsv\n"
        "d = nerfsv.load_dataset(sys.argv[1], 'test')\n"
        "m = nerfsv.Model.load(sys.argv[2])\n"
        "rgb, depth, opacity = m.render(d['poses'][0], 8, 8, tuple(d['intrinsics'][0]))\n"
        "nerfsv.write_png(sys.argv[3], rgb)\n"
    )
    renders = {}
    for width in ["portable", "native"]:
        out = tmp_path / f"{width}.png"
        env = dict(os.environ, NERFSV_KERNELS=width)
        subprocess.run([sys.executable, "-c", script, str(world["ds"]), str(world["model"]), str(out)], env=env,
                       cwd=tmp_path, check=True)
        renders[width] = out.read_bytes()
    assert renders["portable"] == renders["native"]
    bad = subprocess.run([sys.executable, "-c", "import nerfsv"], env=dict(os.environ, NERFSV_KERNELS="sse9"),
                         cwd=tmp_path, capture_output=True, text=True)
    assert bad.returncode != 0 and "NERFSV_KERNELS" in bad.stderr, bad.stderr


def test_python_stress_equals_the_cli(world, tmp_path):
    cli("stress", "--scene", "monolith", "--model", world["model"], "--nerf-field", world["field"], "--config",
        world["study"], "--sampler", "mc", "--replay", "--out", tmp_path / "cli")
    figures = nerfsv.stress(world["model"], tmp_path / "py", sampler="mc", replay=True, config=world["study"],
                            scene="monolith", nerf_field=world["field"])
    assert figures["samplers"][0]["sampler"] == "mc"
    assert stress_files(tmp_path / "py") == stress_files(tmp_path / "cli")


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.mark.parametrize("sampler", ["mc", "cem", "subset"])
def test_a_distributed_run_equals_nerfsv_stress_byte_for_byte(world, tmp_path, local_ray, sampler):
    from nerfsv import distributed

    cli("stress", "--scene", "monolith", "--model", world["model"], "--nerf-field", world["field"], "--config",
        world["study"], "--sampler", sampler, "--replay", "--out", tmp_path / "cli")
    distributed.stress(world["model"], tmp_path / "ray", sampler=sampler, replay=True, config=world["study"],
                       scene="monolith", nerf_field=world["field"], chunk=3)
    assert stress_files(tmp_path / "ray") == stress_files(tmp_path / "cli")
    if sampler == "subset":  # its chains flew as tasks too
        estimator = json.loads((tmp_path / "ray" / "stress.json").read_text())["samplers"][0]["p_fail_estimator"]
        assert "2 levels" in estimator, estimator


def test_a_worker_killed_mid_task_is_retried_and_the_results_are_unchanged(world, tmp_path, local_ray):
    from nerfsv import distributed

    cli("stress", "--scene", "monolith", "--model", world["model"], "--nerf-field", world["field"], "--config",
        world["study"], "--sampler", "mc", "--out", tmp_path / "cli")
    marker = tmp_path / "killed"
    distributed.stress(world["model"], tmp_path / "ray", sampler="mc", config=world["study"], scene="monolith",
                       nerf_field=world["field"], chunk=2, _kill_marker=str(marker))
    assert marker.exists(), "no worker was killed"
    assert stress_files(tmp_path / "ray") == stress_files(tmp_path / "cli")


def test_bad_arguments_raise_value_error_with_the_rust_message(world, tmp_path):
    model = nerfsv.Model.load(world["model"])
    with pytest.raises(ValueError, match="pose: expected shape \\(4, 4\\)"):
        model.render(np.eye(3), 8, 8, (8.0, 8.0, 4.0, 4.0))
    with pytest.raises(ValueError, match="points: expected shape"):
        model.density(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="sampler: unknown sampler \"nope\": one of mc, cem, subset"):
        nerfsv.stress(world["model"], tmp_path / "s", sampler="nope")
    with pytest.raises(ValueError, match="disturbances: expected shape"):
        nerfsv.fly(world["model"], disturbances=np.zeros((2, 3)), scene="monolith", nerf_field=world["field"])
    far = np.zeros((6, 12))
    far[2, 3] = 1e300  # finite, but far outside the prior: refused as `nerfsv fly --disturbances` refuses it
    with pytest.raises(ValueError, match=r"disturbances\[2, 3\] \(dv_x\) is 1e\+?300, beyond the prior's support"):
        nerfsv.fly(world["model"], disturbances=far, scene="monolith", nerf_field=world["field"])
    bad = tmp_path / "bad.toml"
    bad.write_text(STUDY.replace("m_elite = 2", "m_elite = 7"))
    with pytest.raises(ValueError, match="stress.cem.m_elite"):
        nerfsv.stress(world["model"], tmp_path / "s", config=bad, scene="monolith", nerf_field=world["field"])
    with pytest.raises(ValueError, match="unknown scene|nope"):
        nerfsv.ground_truth_field("nope")
    with pytest.raises(FileNotFoundError, match="missing.safetensors"):
        nerfsv.Model.load(tmp_path / "missing.safetensors")
    with pytest.raises(ValueError, match="steps"):
        nerfsv.train(world["ds"], tmp_path / "t", steps=0)


def test_training_reports_progress_and_gives_a_model(world, tmp_path):
    seen = []
    model = nerfsv.train(world["ds"], tmp_path / "nerf", steps=2, config=world["nerf_toml"], progress=seen.append)
    assert [p["step"] for p in seen] == [1, 2] and all(np.isfinite(p["loss"]) for p in seen)
    assert Path(model.path).is_file()
    # The command line's --set: the config's keys overridden, a key that is none refused by name.
    nerfsv.train(world["ds"], tmp_path / "over", config=world["nerf_toml"], overrides=["train_steps=1"])
    assert json.loads((tmp_path / "over" / "train_stats.json").read_text())["steps"] == 1
    with pytest.raises(ValueError, match="--set train.batch_ray=8"):
        nerfsv.train(world["ds"], tmp_path / "bad", steps=1, config=world["nerf_toml"], overrides=["train.batch_ray=8"])


def test_the_command_line_entry_runs_the_study_of_nerfsv_stress(world, tmp_path):
    import sys

    from nerfsv.distributed import outputs

    cli("stress", "--scene", "monolith", "--model", world["model"], "--nerf-field", world["field"], "--config",
        world["study"], "--sampler", "mc", "--out", tmp_path / "cli")
    entry = [sys.executable, "-m", "nerfsv.distributed", "--model", str(world["model"]), "--nerf-field",
             str(world["field"]), "--scene", "monolith", "--sampler", "mc", "--chunk", "3"]
    r = subprocess.run([*entry, "--config", str(world["study"]), "--out", str(tmp_path / "ray")], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["samplers"][0]["rollouts"] == 8
    assert outputs(tmp_path / "ray") == outputs(tmp_path / "cli")
    bad = tmp_path / "bad.toml"
    bad.write_text(STUDY.replace("rollouts = 8", "rollouts = 0"))
    r = subprocess.run([*entry, "--config", str(bad), "--out", str(tmp_path / "bad")], capture_output=True, text=True)
    assert r.returncode == 1 and "stress.monte_carlo.rollouts" in r.stderr, r.stderr
