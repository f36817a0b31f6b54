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
    return model.uncertainty(method, _f32(pose), width, height, intrinsics, _f32(image), config, list(overrides))


def fly(
    model: Union[Path, Model],
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
    """Flies the drone once along its planned path (``nerfsv fly``). ``model`` is a checkpoint's
    path or a ``Model``: a ``Model`` flies from the file it was loaded from (``Model.path``),
    which must still hold it (else ``ValueError``), or, when that file is gone, from a temporary
    copy of it; the results are the same as with its path. ``disturbances`` is
    ``[steps, 12]`` float64, or ``random_seed`` draws them from the prior. Returns
    ``figures`` (a dict) and the trajectory at every substep: ``time`` ``[n]``, ``position``
    and ``estimate`` ``[n, 3]``, ``clearance`` ``[n]`` (NaN outside the field's grid)."""
    d = None if disturbances is None else np.ascontiguousarray(disturbances, dtype=np.float64)
    out = _nerfsv.fly(model, world, estimator, d, random_seed, seed, config, scene, mesh, nerf_field, list(overrides))
    out["figures"] = json.loads(out["figures"])
    return out


def stress(
    model: Union[Path, Model, None] = None,
    out: Optional[Path] = None,
    *,
    system: Any = None,
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
    reward: Optional[str] = None,
    measure: Optional[str] = None,
    uncertainty: str = "exact",
    field: Optional[Path] = None,
    std: Union[float, Sequence[float], None] = None,
    proposal: Optional[Tuple[np.ndarray, np.ndarray]] = None,
) -> Dict[str, Any]:
    """A stress test: of the drone (``model``, ``out``), or of your own ``system``.

    **The drone** runs ``nerfsv stress`` into ``out`` (the same files: ``rollouts.csv``,
    ``table.csv``, ``stress.json``, the replays, the journal) and returns ``stress.json``'s
    figures. ``model`` is a checkpoint's path or a ``Model`` (as ``fly``). ``sampler`` is
    ``"mc"``, ``"cem"`` or ``"subset"``; ``seed`` replaces the config's ``stress.seed``.
    ``reward`` or ``measure`` (``"ga"`` or ``"bla"``) measures that method's uncertainty at
    every step, ``reward`` also ranking CEM's samples by its reward (eq. 10/11), measured as
    ``uncertainty`` says (``"exact"``, or ``"field"`` from the uncertainty field file ``field``,
    ``nerfsv uq field``): the command line's ``--reward``, ``--measure``, ``--uncertainty``,
    ``--field``, so the online tables with and without reward come from Python too.
    ``executor`` flies the rollouts elsewhere (``nerfsv.distributed`` builds one on Ray); the
    files are the same bytes either way. ``overrides`` are the run config's
    ``"TABLE.KEY=VALUE"`` overrides, as the command line's ``--set``.

    **Your own system** (``system=obj``): ``obj.steps`` and ``obj.dim`` are ints and
    ``obj.run(disturbances, seed)`` flies one rollout, ``disturbances`` ``[steps, dim]``
    float64 and ``seed`` an int for the system's own randomness, and returns ``(failed,
    miss_distance)``: ``failed`` a bool, ``miss_distance`` a finite float, a pass's distance to
    failure (≥ 0). Optionally ``obj.run_batch(disturbances [n, steps, dim], seeds [n])`` returns
    a sequence of ``n`` such pairs: then each batch of rollouts a sampler flies is one call (subset
    simulation: one per level 0 and per move of every chain), else ``run`` is called for each.
    ``run`` must be a function of its arguments alone (a recorded rollout is not run again).

    The samplers' score is ``miss_distance`` for a pass (0 counts as the smallest positive
    number) and ``min(miss_distance, 0)`` for a failure, so failure ⇔ score ≤ 0; a pass with a
    negative miss distance, a miss distance that is not finite, or a return that is not such a
    pair raises ``ValueError`` naming the call and the rollout's seed. An exception ``run``
    raises propagates as itself.

    ``sampler``: ``"mc"`` (``[stress.monte_carlo]``), ``"cem"`` (``[stress.cem]``,
    ending with its importance-sampling estimate), ``"is"`` (importance sampling from
    ``proposal=(mean, std)``, each broadcast to ``[steps, dim]``, ``stress.cem.is_samples``
    rollouts) or ``"subset"`` (``[stress.subset]``), with the settings of ``config`` and
    ``overrides``. The prior is N(0, diag(``std``²)) per step (``std`` a number or one per
    component), else the config's ``[stress.disturbance]``. ``seed`` (default
    ``stress.seed``) fixes every rollout: the same seed gives the same results. With
    ``out``, ``out/rollouts.csv`` holds every rollout (the command line's layout) and
    ``out/journal`` every finished one as it finishes, so that ``resume=True`` after an
    interrupted call finishes with the same results without running the recorded rollouts again.
    A journal belongs to the settings above, the system's class name and ``str(obj.key)`` when
    ``obj`` has a ``key`` attribute (give one that names whatever else its results depend on):
    resuming into another's raises ``ValueError``.

    Returns a dict: ``sampler``, ``estimator``, ``probability``, ``standard_error``,
    ``interval`` (95 %), ``rollouts``, ``failures``, ``seed``, per rollout (in the CSV's order)
    ``scores``, ``failed``, ``seeds`` and ``labels`` (the CSV's sampler column: ``"mc"``,
    ``"cem"``, ``"cem-is"`` for an importance batch, ``"subset"``), ``most_likely_failure`` (``label``,
    ``population``, ``index``, ``seed``, ``score``, ``log_p``, ``disturbances``, or ``None``),
    and the sampler's own fields: for ``"cem"`` and ``"is"`` ``effective_sample_size``,
    ``effective_failures``, ``unnormalised`` and its ``unnormalised_standard_error``,
    ``is_samples``, ``is_failures``, ``proposal_mean`` and ``proposal_std`` (the proposal the
    estimate's batch came from), for ``"cem"`` ``search_failures``; for ``"subset"`` ``cov``,
    ``levels``, ``last_level_failures``, ``effective_failures``, ``equivalent_rollouts``,
    ``thresholds``, ``acceptance``. For ``"mc"`` ``standard_error`` is the binomial
    √(p(1 − p)/n) and ``interval`` Wilson's.
    """
    if system is not None:
        drone = dict(model=(model, None), world=(world, "nerf"), estimator=(estimator, "vision"),
                     replay=(replay, False), scene=(scene, "stonehenge"), mesh=(mesh, None),
                     nerf_field=(nerf_field, None), executor=(executor, None), reward=(reward, None),
                     measure=(measure, None), uncertainty=(uncertainty, "exact"), field=(field, None))
        given = [k for k, (v, default) in drone.items() if v is not default and v != default]
        if given:
            raise ValueError(f"system: {', '.join(given)}: the drone's arguments, not a system's")
        return _stress_system(system, out, sampler, seed, config, resume, overrides, std, proposal)
    if model is None or out is None:
        raise ValueError("stress: give model and out (the drone), or system=")
    if std is not None or proposal is not None:
        raise ValueError("std, proposal: are read only with system=")
    return json.loads(
        _nerfsv.stress(
            model, out, sampler, world, estimator, replay, seed, config, scene, mesh, nerf_field, resume, executor,
            list(overrides), reward, measure, uncertainty, field,
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


def _stress_system(system, out, sampler, seed, config, resume, overrides, std, proposal) -> Dict[str, Any]:
    dim = getattr(system, "dim", None)
    stds = None
    if std is not None:
        stds = np.atleast_1d(np.asarray(std, dtype=np.float64))
        if stds.shape == (1,) and isinstance(dim, int):
            stds = np.repeat(stds, dim)
        stds = [float(v) for v in stds.ravel()]
    mean = q_std = None
    if proposal is not None:
        shape = (getattr(system, "steps", None), dim)
        mean, q_std = (np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=np.float64), shape)) for a in proposal)
    settings = dict(std=stds, seed=seed, config=config, overrides=list(overrides), out=out, resume=resume,
                    proposal_mean=mean, proposal_std=q_std)
    return _nerfsv.stress_system(system, sampler, settings)


def _f32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)
