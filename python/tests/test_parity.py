"""The study's parts from Python against the command line and the files' own layouts: a model's
state dict against the safetensors file read by hand, the offline uncertainty rows against
`nerfsv uq offline`'s CSV, the AUSE against `nerfsv uq ause`, the per-pixel maps against the
AUSE they give, and a rendered dataset against `nerfsv scene`'s files byte for byte.

The fixtures are built on the fly with the `nerfsv` binary (NERFSV_BIN, else the workspace's
target/release/nerfsv): a 16×16 monolith dataset (16×16 = 256 pixels: an image needs 100 with a
ground-truth depth to be scored) and a 2-step model in a ±1 m box.
"""

import csv
import json
import math
import re
import struct
from pathlib import Path

import numpy as np
import pytest

import nerfsv

from common import ROOT, cli, tiny_world

SIZE = 16


@pytest.fixture(scope="session")
def world(tmp_path_factory):
    return tiny_world(tmp_path_factory.mktemp("parity"), size=SIZE, test=2)


def read_safetensors(path):
    """The tensors of a safetensors file by its documented layout: an 8-byte little-endian
    header length, a JSON header of dtype / shape / data_offsets (into the bytes after it) per
    tensor and `__metadata__`, then the raw little-endian data."""
    buf = Path(path).read_bytes()
    (n,) = struct.unpack("<Q", buf[:8])
    header = json.loads(buf[8:8 + n])
    header.pop("__metadata__", None)
    dtypes = {"F32": "<f4", "F64": "<f8", "I64": "<i8", "U8": "u1"}
    out = {}
    for name, t in header.items():
        start, end = t["data_offsets"]
        data = np.frombuffer(buf[8 + n + start:8 + n + end], dtype=dtypes[t["dtype"]])
        out[name] = (t["dtype"], data.reshape(t["shape"]))
    return out


def test_the_state_dict_is_the_checkpoint_file_s_tensors(world):
    on_disk = read_safetensors(world["model"])
    model = nerfsv.Model.load(world["model"])
    weights = model.state_dict()
    assert set(weights) == {k for k in on_disk if not k.startswith("optimizer.")}
    assert {"encoder.embeddings", "sigma_net.0.weight", "color_net.2.weight", "density_grid"} <= set(weights)
    full = model.state_dict(optimizer=True)
    assert set(full) == set(on_disk), "a training checkpoint holds Adam's moments of every weight tensor"
    for name, (dtype, expected) in on_disk.items():
        got = full[name]
        assert dtype == "F32" and got.dtype == np.float32, name
        assert got.shape == expected.shape and np.array_equal(got, expected), name
        if name in weights:
            assert np.array_equal(weights[name], expected), name


def write_safetensors(path, tensors, metadata):
    """A safetensors file by the same layout: `tensors` name → float32 array, `metadata` str → str;
    the header padded with spaces to a multiple of 8 bytes."""
    header, data, offset = {"__metadata__": metadata}, [], 0
    for name, a in sorted(tensors.items()):
        raw = np.ascontiguousarray(a, dtype="<f4").tobytes()
        header[name] = {"dtype": "F32", "shape": list(a.shape), "data_offsets": [offset, offset + len(raw)]}
        data.append(raw)
        offset += len(raw)
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 8)
    Path(path).write_bytes(struct.pack("<Q", len(text)) + text + b"".join(data))


def test_a_checkpoint_without_training_state_has_weights_but_no_optimiser(world, tmp_path):
    buf = Path(world["model"]).read_bytes()
    (n,) = struct.unpack("<Q", buf[:8])
    meta = json.loads(buf[8:8 + n])["__metadata__"]
    kept = {"format", "format_version", "nerf_config", "aabb", "step", "seed"}
    model_only = {k: v for k, v in meta.items() if k in kept}
    weights = {k: a for k, (_, a) in read_safetensors(world["model"]).items() if not k.startswith("optimizer.")}
    write_safetensors(tmp_path / "weights.safetensors", weights, model_only)
    model = nerfsv.Model.load(tmp_path / "weights.safetensors")
    got = model.state_dict()
    assert set(got) == set(weights) and all(np.array_equal(got[k], weights[k]) for k in weights)
    with pytest.raises(ValueError, match="train_config|optimizer"):
        model.state_dict(optimizer=True)
    # The same tensors, one value changed: the state dict follows the file.
    weights["sigma_net.1.weight"] = weights["sigma_net.1.weight"].copy()
    weights["sigma_net.1.weight"][3, 5] += 0.25
    write_safetensors(tmp_path / "changed.safetensors", weights, model_only)
    changed = nerfsv.Model.load(tmp_path / "changed.safetensors").state_dict()
    assert not np.array_equal(changed["sigma_net.1.weight"], got["sigma_net.1.weight"])
    assert np.array_equal(changed["sigma_net.1.weight"], weights["sigma_net.1.weight"])


def readme_block(heading):
    """The first ```python block under `## heading` of python/README.md."""
    text = (ROOT / "python" / "README.md").read_text()
    section = text.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_readme_s_pytorch_recipe_loads_the_weights_into_a_module(world):
    torch = pytest.importorskip("torch")
    scope = {"checkpoint": str(world["model"])}
    exec(readme_block("PyTorch"), scope)
    module, on_disk = scope["module"], read_safetensors(world["model"])
    state = module.state_dict()
    assert set(state) == {k for k in on_disk if not k.startswith("optimizer.")}
    for name, value in state.items():
        assert value.dtype == torch.float32 and np.array_equal(value.numpy(), on_disk[name][1]), name


def test_safetensors_torch_reads_the_checkpoint_as_the_state_dict(world):
    """The README's way without nerfsv: `safetensors.torch.load_file` gives the same tensors,
    the optimiser's included."""
    pytest.importorskip("torch")
    load_file = pytest.importorskip("safetensors.torch").load_file
    tensors = load_file(str(world["model"]))
    full = nerfsv.Model.load(world["model"]).state_dict(optimizer=True)
    assert set(tensors) == set(full)
    for name, t in tensors.items():
        assert np.array_equal(t.numpy(), full[name]), name


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


@pytest.mark.parametrize("method, max_images, rays", [("ga", None, None), ("ga", 1, 50), ("bla", 1, None)])
def test_offline_rows_and_summary_equal_nerfsv_uq_offline(world, tmp_path, method, max_images, rays):
    args = ["uq", "offline", "--method", method, "--model", world["model"], "--data", world["ds"], "--out", tmp_path]
    args += [] if max_images is None else ["--max-images", max_images]
    args += [] if rays is None else ["--rays", rays]
    cli(*args)
    model = nerfsv.Model.load(world["model"])
    got = nerfsv.uncertainty_offline(model, world["ds"], method, max_images=max_images, rays=rays)
    header, rows = read_csv(tmp_path / f"uq_{method}.csv")
    assert list(got["rows"]) == header, "the CSV's columns, in its order"
    assert len(rows) == (5 if max_images is None else 3)
    text = {"split", "file_path", "excluded", "note"}
    for j, name in enumerate(header):
        column = got["rows"][name]
        assert isinstance(column, np.ndarray) and len(column) == len(rows), name
        cells = [r[j] for r in rows]
        if name in text:
            assert column.tolist() == cells, name
        elif name == "index":
            assert column.dtype == np.int64 and column.tolist() == [int(c) for c in cells]
        else:
            expected = np.array([float(c) if c else math.nan for c in cells])
            assert column.dtype == np.float64 and np.array_equal(column, expected, equal_nan=True), name
    summary = json.loads((tmp_path / f"uq_{method}.json").read_text())
    assert {k: v for k, v in got["summary"].items() if k != "seconds"} == {
        k: v for k, v in summary.items() if k != "seconds"
    }


def sparsification_ause(error, uncertainty):
    """The depth AUSE by the definition of crates/uq/src/ause.rs, in numpy: over the pixels with
    a finite error, remove the most uncertain (no finite uncertainty counts as the largest,
    ties by pixel order) and take the remaining mean at 100 fractions, against the oracle that
    removes the largest errors first; both curves over their shared maximum; trapezoid rule."""
    keep = np.isfinite(error)
    e = error[keep].astype(np.float64)
    u = uncertainty[keep]
    u = np.where(np.isfinite(u), u, np.inf)
    n = len(e)
    steps = 100

    def curve(ordered):
        prefix = np.concatenate([[0.0], np.cumsum(ordered)])
        kept = np.array([(steps - k) * n // steps for k in range(steps)])
        return prefix[kept] / kept

    by_u = curve(e[np.argsort(u, kind="stable")])
    oracle = curve(np.sort(e))
    top = max(by_u.max(), oracle.max())
    scale = 1.0 / top if top > 0 else 0.0
    gap = (by_u - oracle) * scale
    x = np.arange(steps) / steps
    return float(np.sum(0.5 * (x[1:] - x[:-1]) * (gap[1:] + gap[:-1]))), n, int(np.sum(~np.isfinite(u)))


@pytest.mark.parametrize("method", ["ga", "bla"])
def test_ause_and_the_maps_it_scores_equal_nerfsv_uq_ause(world, method):
    expected = json.loads(cli("uq", "ause", "--method", method, "--model", world["model"], "--data", world["ds"],
                              "--split", "test", "--json"))
    model = nerfsv.Model.load(world["model"])
    got = nerfsv.uncertainty_ause(model, world["ds"], method, split="test")
    for key in ["method", "split", "images", "skipped", "mean_ause", "per_image"]:
        assert got[key] == expected[key], key
    assert got["images"] >= 1, "the fixture must score an image, or this test says nothing about the maps"

    data = nerfsv.load_dataset(world["ds"], "test", depth=True)
    scored = {im["image"]: im for im in expected["per_image"]}
    for i, name in enumerate(data["names"]):
        pose, k = data["poses"][i], tuple(data["intrinsics"][i])
        maps = nerfsv.uncertainty_maps(model, method, pose, SIZE, SIZE, k, data["images"][i], depth=data["depths"][i])
        assert {maps[m].shape for m in ["depth", "depth_std", "depth_error"]} == {(SIZE, SIZE)}
        assert maps["depth_std"].dtype == np.float32
        _, depth, _ = model.render(pose, SIZE, SIZE, k)
        assert np.array_equal(maps["depth"], depth)
        gt = data["depths"][i]
        valid = gt > 0
        assert np.array_equal(np.isnan(maps["depth_error"]), ~valid)
        assert np.array_equal(maps["depth_error"][valid], np.abs(depth - gt)[valid])
        if name in scored:
            ause, pixels, unscored = sparsification_ause(maps["depth_error"].ravel(), maps["depth_std"].ravel())
            assert (pixels, unscored) == (scored[name]["pixels"], scored[name]["unscored"])
            assert ause == pytest.approx(scored[name]["ause"], rel=1e-12, abs=1e-15)
        # The fit on the way to the maps is the image's fit.
        assert maps["fit"] == nerfsv.uncertainty(model, method, pose, SIZE, SIZE, k, data["images"][i])


def tree(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(Path(folder).rglob("*")) if p.is_file()}


MESH = ROOT / "tests" / "fixtures" / "meshes" / "world.ply"


@pytest.mark.parametrize("world_args, world_kwargs", [(["--scene", "pillars"], {"scene": "pillars"}),
                                                      (["--mesh", MESH], {"mesh": MESH})])
def test_render_dataset_writes_the_files_of_nerfsv_scene_byte_for_byte(tmp_path, world_args, world_kwargs):
    cli("scene", *world_args, "--out", tmp_path / "cli", "--width", 8, "--height", 6, "--train", 2, "--val", 1,
        "--test", 1, "--supersample", 1, "--seed", 4, "--fov", 0.9, "--close-up", 0.5)
    options = dict(width=8, height=6, train=2, val=1, test=1, supersample=1, fov=0.9, close_up=0.5)
    figures = nerfsv.render_dataset(tmp_path / "py", **world_kwargs, seed=4, **options)
    assert figures["views"] == 4
    cli_files, py_files = tree(tmp_path / "cli"), tree(tmp_path / "py")
    assert "transforms_train.json" in cli_files and "scene.json" in cli_files and "test/r_0_depth.png" in cli_files
    assert cli_files == py_files
    # The defaults are the command's: seed 0 there and here, other cameras than seed 4's.
    cli("scene", *world_args, "--out", tmp_path / "cli0", "--width", 8, "--height", 6, "--train", 2, "--val", 1,
        "--test", 1, "--supersample", 1, "--fov", 0.9, "--close-up", 0.5)
    nerfsv.render_dataset(tmp_path / "py0", **world_kwargs, **options)
    assert tree(tmp_path / "py0") == tree(tmp_path / "cli0") != py_files


def test_render_dataset_refuses_bad_options_by_their_argument_before_writing(tmp_path):
    with pytest.raises(ValueError, match="fov"):
        nerfsv.render_dataset(tmp_path / "bad", scene="pillars", fov=4.0)
    with pytest.raises(ValueError, match="width"):
        nerfsv.render_dataset(tmp_path / "bad", scene="pillars", width=0)
    with pytest.raises(FileNotFoundError, match="missing.obj"):
        nerfsv.render_dataset(tmp_path / "bad", mesh=tmp_path / "missing.obj")
    assert not (tmp_path / "bad").exists()


def test_the_study_functions_refuse_bad_arguments_with_the_rust_message(world, tmp_path):
    model = nerfsv.Model.load(world["model"])
    with pytest.raises(ValueError, match="method: .*nope"):
        nerfsv.uncertainty_offline(model, world["ds"], "nope")
    with pytest.raises(ValueError, match="max_images"):
        nerfsv.uncertainty_offline(model, world["ds"], max_images=0)
    with pytest.raises(ValueError, match="rays"):
        nerfsv.uncertainty_offline(model, world["ds"], rays=0)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="not a dataset folder"):
        nerfsv.uncertainty_offline(model, tmp_path / "empty")
    with pytest.raises(ValueError, match='no transforms file for split "nope"'):
        nerfsv.uncertainty_ause(model, world["ds"], split="nope")
    with pytest.raises(ValueError, match="uq.nope"):
        nerfsv.uncertainty_ause(model, world["ds"], overrides=["uq.nope=1"])
    data = nerfsv.load_dataset(world["ds"], "test")
    k = tuple(data["intrinsics"][0])
    with pytest.raises(ValueError, match="depth: expected shape \\(16, 16\\)"):
        nerfsv.uncertainty_maps(model, "ga", data["poses"][0], SIZE, SIZE, k, data["images"][0], depth=np.zeros((4, 4)))
    with pytest.raises(ValueError, match="supersample"):
        nerfsv.render_view(data["poses"][0], SIZE, SIZE, k, supersample=0)


def test_render_view_is_the_dataset_s_image_before_it_is_written(world):
    data = nerfsv.load_dataset(world["ds"], "train", depth=True)
    for i in range(len(data["names"])):
        rgba, depth = nerfsv.render_view(data["poses"][i], SIZE, SIZE, tuple(data["intrinsics"][i]),
                                         scene="monolith", supersample=1)
        assert rgba.shape == (SIZE, SIZE, 4) and depth.shape == (SIZE, SIZE) and rgba.dtype == np.float32
        # The files hold 8-bit colour and 16-bit millimetres, rounded.
        assert np.abs(rgba - data["images"][i]).max() <= 0.5 / 255 + 1e-6
        assert np.abs(depth - data["depths"][i]).max() <= 0.0005 + 1e-6
    pillars = nerfsv.render_view(data["poses"][i], SIZE, SIZE, tuple(data["intrinsics"][i]), scene="pillars",
                                 supersample=1)[0]
    assert not np.array_equal(pillars, rgba), "another scene is another picture"
