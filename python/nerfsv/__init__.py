"""nerfsv from Python: safety validation of a vision-based quadcopter flying through a Neural
Radiance Field.

The functions call the same Rust library as the ``nerfsv`` command line; arrays are numpy
arrays (float32 for images, points and fields, float64 for the drone), figures are dicts.
Errors raise ``ValueError`` (a bad argument, a file that is not what it should be) or
``OSError`` (a file that cannot be read or written), with the Rust message.

>>> import nerfsv
>>> model = nerfsv.Model.load("runs/stonehenge/nerf/checkpoint.safetensors")   # doctest: +SKIP
>>> rgb, depth, opacity = model.render(pose, 100, 100, (fx, fy, cx, cy))       # doctest: +SKIP

``nerfsv.distributed`` runs ``stress`` with its rollouts fanned out as Ray tasks.
"""

from __future__ import annotations

import json
from os import PathLike
from typing import Any, Callable, Dict, Iterable, Optional, Sequence, Tuple, Union

import numpy as np

from . import _nerfsv
from ._nerfsv import Model, ground_truth_field, load_dataset, load_field, render_view, write_depth_png, write_png

__version__ = _nerfsv.__version__

Path = Union[str, "PathLike[str]"]

__all__ = [
    "Model",
    "load_dataset",
    "train",
    "ground_truth_field",
    "load_field",
    "uncertainty",
    "fly",
    "stress",
    "write_png",
    "write_depth_png",
    "render_dataset",
    "render_view",
    "uncertainty_offline",
    "uncertainty_ause",
    "uncertainty_maps",
]


def train(
    data: Path,
    out: Path,
    *,
    steps: Optional[int] = None,
    seconds: Optional[float] = None,
    config: Optional[Path] = None,
    seed: Optional[int] = None,
    resume: bool = False,
    progress: Optional[Callable[[Dict[str, float]], Any]] = None,
    overrides: Sequence[str] = (),
) -> Model:
    """Trains a NeRF on the train split of the Blender-format dataset ``data`` into ``out``
    (``checkpoint.safetensors`` and the training statistics, as ``nerfsv train`` writes them),
    for ``steps`` steps (default: the config's ``train_steps``, 2000) or ``seconds`` seconds. ``progress(dict)`` is called
    after every step with ``step``, ``fraction``, ``elapsed_s``, ``loss``, ``psnr``. ``config`` is
    a run config (``nerfsv config`` prints one; its ``[nerf]``, ``[train]`` and ``train_steps``
    are read) and ``overrides`` its ``"TABLE.KEY=VALUE"`` overrides, as the command line's
    ``--set``."""
    return _nerfsv.train(data, out, steps, seconds, config, seed, resume, progress, list(overrides))


def uncertainty(
    model: Model,
    method: str,
    pose: np.ndarray,
    width: int,
    height: int,
    intrinsics: Tuple[float, float, float, float],
    image: np.ndarray,
    config: Optional[Path] = None,
    overrides: Sequence[str] = (),
) -> Dict[str, Any]:
    """The paper's uncertainty of one image: ``method`` ``"ga"`` (σ_d of eq. 10) or ``"bla"``
    (the normalised trace and rmv of eq. 11). ``image`` is ``[h, w, 4]`` RGBA or ``[h, w, 3]``
    RGB in ``[0, 1]``; ``config`` a run config whose ``[uq]`` table sets the fit, with
    ``overrides`` (``"uq.KEY=VALUE"``). Returns the figures; ``None`` when every ray misses the
    model."""
    return json.loads(
        model.uncertainty(method, _f32(pose), width, height, intrinsics, _f32(image), config, list(overrides))
    )


def fly(
    model: Path,
    *,
    world: str = "nerf",
    estimator: str = "vision",
    disturbances: Optional[np.ndarray] = None,
    random_seed: Optional[int] = None,
    seed: Optional[int] = None,
    config: Optional[Path] = None,
    scene: str = "stonehenge",
    mesh: Optional[Path] = None,
    nerf_field: Optional[Path] = None,
    overrides: Sequence[str] = (),
) -> Dict[str, Any]:
    """Flies the drone once along its planned path (``nerfsv fly``). ``disturbances`` is
    ``[steps, 12]`` float64, or ``random_seed`` draws them from the prior. Returns
    ``figures`` (a dict) and the trajectory at every substep: ``time`` ``[n]``, ``position``
    and ``estimate`` ``[n, 3]``, ``clearance`` ``[n]`` (NaN outside the field's grid)."""
    d = None if disturbances is None else np.ascontiguousarray(disturbances, dtype=np.float64)
    out = _nerfsv.fly(model, world, estimator, d, random_seed, seed, config, scene, mesh, nerf_field, list(overrides))
    out["figures"] = json.loads(out["figures"])
    return out


def stress(
    model: Path,
    out: Path,
    *,
    sampler: str = "cem",
    world: str = "nerf",
    estimator: str = "vision",
    replay: bool = False,
    seed: Optional[int] = None,
    config: Optional[Path] = None,
    scene: str = "stonehenge",
    mesh: Optional[Path] = None,
    nerf_field: Optional[Path] = None,
    resume: bool = False,
    executor: Optional[Callable[[str, str, list], Iterable[Tuple[int, bytes]]]] = None,
    overrides: Sequence[str] = (),
) -> Dict[str, Any]:
    """Runs ``nerfsv stress`` into ``out`` (the same files: ``rollouts.csv``, ``table.csv``,
    ``stress.json``, the replays, the journal) and returns ``stress.json``'s figures.
    ``sampler`` is ``"mc"``, ``"cem"`` or ``"subset"``; ``seed`` replaces the config's
    ``validation.seed``. ``executor`` flies the rollouts elsewhere (``nerfsv.distributed``
    builds one on Ray); the files are the same bytes either way. ``overrides`` are the run
    config's ``"TABLE.KEY=VALUE"`` overrides, as the command line's ``--set``."""
    return json.loads(
        _nerfsv.stress(
            model, out, sampler, world, estimator, replay, seed, config, scene, mesh, nerf_field, resume, executor,
            list(overrides),
        )
    )


def render_dataset(
    out: Path,
    *,
    scene: str = "stonehenge",
    mesh: Optional[Path] = None,
    width: Optional[int] = None,
    height: Optional[int] = None,
    train: Optional[int] = None,
    val: Optional[int] = None,
    test: Optional[int] = None,
    fov: Optional[float] = None,
    close_up: Optional[float] = None,
    supersample: Optional[int] = None,
    seed: Optional[int] = None,
) -> Dict[str, Any]:
    """Renders the Blender-format dataset ``nerfsv scene --out OUT`` renders, the same files byte
    for byte: the ground truth ``scene`` (a built-in name) or ``mesh`` (a mesh file, metres, z
    up) seen by ``train`` / ``val`` / ``test`` cameras (default 200 / 150 / 150) of ``width`` ×
    ``height`` pixels (default 100 × 100), horizontal field of view ``fov`` (radians, default
    0.8), ``close_up`` the fraction of views at drone altitude (default 0), ``supersample`` n×n
    samples per pixel (default 2), ``seed`` the camera placement's (default 0). ``out`` is
    replaced if it holds a dataset. Returns the figures (``scene``, ``views``, ``width``,
    ``height``, ``seconds``, ``primary_rays_per_second``)."""
    return json.loads(
        _nerfsv.render_dataset(out, scene, mesh, width, height, train, val, test, fov, close_up, supersample, seed)
    )


def uncertainty_offline(
    model: Model,
    data: Path,
    method: str = "ga",
    *,
    max_images: Optional[int] = None,
    rays: Optional[int] = None,
    downscale: int = 1,
    config: Optional[Path] = None,
    overrides: Sequence[str] = (),
) -> Dict[str, Any]:
    """``nerfsv uq offline`` without its files: ``method`` (``"ga"`` or ``"bla"``) on every image
    of the dataset folder ``data``'s train, val and test splits (those whose transforms file is
    there; the first ``max_images`` of each), ``rays`` rays per image at most (GA: default every
    pixel; BLA: default the config's ``uq.max_rays``), images downscaled by ``downscale``.

    Returns ``rows``, the columns of ``uq_METHOD.csv`` under its header's names and in its order
    (``split`` and ``file_path`` str arrays, ``index`` int64, the method's values float64 with
    NaN where the CSV is empty, GA's ``excluded`` or BLA's ``note`` str arrays: ``""``,
    ``"absolutely_certain"``, ``"absolutely_uncertain"``, ``"all_rays_miss"``;
    ``pandas.DataFrame(rows)`` is the CSV), and ``summary``, ``uq_METHOD.json``'s per-split
    figures."""
    cols, summary = _nerfsv.uncertainty_offline(
        model, data, method, max_images, rays, downscale, config, list(overrides)
    )
    rows = {k: v if isinstance(v, np.ndarray) else np.asarray(v, dtype=str) for k, v in cols.items()}
    return {"rows": rows, "summary": json.loads(summary)}


def uncertainty_ause(
    model: Model,
    data: Path,
    method: str = "ga",
    *,
    split: str = "test",
    max_images: Optional[int] = None,
    config: Optional[Path] = None,
    overrides: Sequence[str] = (),
) -> Dict[str, Any]:
    """``nerfsv uq ause --json``: the depth AUSE of ``method``'s per-pixel depth uncertainty on
    the images of ``split`` (the first ``max_images``) of the dataset folder ``data``, which
    must hold ground-truth depth. Returns ``method``, ``split``, ``images`` (scored),
    ``skipped`` (the reasons), ``mean_ause`` (``None`` when none was scored), ``per_image``
    (``image``, ``ause``, ``pixels``, ``unscored``) and ``seconds``."""
    return json.loads(_nerfsv.uncertainty_ause(model, data, method, split, max_images, config, list(overrides)))


def uncertainty_maps(
    model: Model,
    method: str,
    pose: np.ndarray,
    width: int,
    height: int,
    intrinsics: Tuple[float, float, float, float],
    image: np.ndarray,
    depth: Optional[np.ndarray] = None,
    config: Optional[Path] = None,
    overrides: Sequence[str] = (),
) -> Dict[str, Any]:
    """One view's per-pixel maps, those ``nerfsv uq ause`` scores and the ``uq`` stage draws in
    ``uq_maps.png``: ``depth`` ``[h, w]`` the model's z-depth (metres), ``depth_std`` ``[h, w]``
    ``method``'s depth standard deviation (metres; NaN where a ray composites no sample; BLA
    linearised at its posterior mode), ``depth_error`` ``[h, w]`` ``|depth − ground truth|``
    (metres, NaN where ``depth``, the ground truth, is 0) when ``depth`` is given, all float32;
    and ``fit``, the image's figures as ``uncertainty`` returns them (``None`` when every ray
    misses the model, and ``depth_std`` is NaN everywhere). The arguments as ``uncertainty``'s."""
    d = None if depth is None else _f32(depth)
    out = _nerfsv.uncertainty_maps(
        model, method, _f32(pose), width, height, intrinsics, _f32(image), d, config, list(overrides)
    )
    out["fit"] = json.loads(out["fit"])
    return out


def _f32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)
