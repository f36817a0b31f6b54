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
from ._nerfsv import Model, ground_truth_field, load_dataset, load_field, write_depth_png, write_png

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


def _f32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)
