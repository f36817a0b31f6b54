"""Type stubs of the Rust extension module (see nerfsv/__init__.py for the documented API)."""

from os import PathLike
from typing import Any, Callable, Dict, Iterable, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, PathLike[str]]
_Intrinsics = Tuple[float, float, float, float]

__version__: str

class Model:
    """A trained NeRF and the checkpoint it was read from.

    Poses are 4×4 camera-to-world matrices (row-major, metres, OpenGL camera axes: x right,
    y up, looking along −z), as in a Blender / nerfstudio ``transforms.json``; intrinsics are
    pixels ``(fx, fy, cx, cy)``.
    """

    @staticmethod
    def load(path: _Path) -> Model:
        """Reads a checkpoint (``checkpoint.safetensors`` of ``nerfsv train``)."""
        ...
    @property
    def path(self) -> str:
        """The checkpoint this model was read from."""
        ...
    @property
    def aabb(self) -> Tuple[List[float], List[float]]:
        """The scene box the model covers: ``(min, max)``, metres."""
        ...
    def render(
        self, pose: npt.ArrayLike, width: int, height: int, intrinsics: _Intrinsics,
        background: Tuple[float, float, float] = ...,
    ) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """Renders the view of a camera: ``(rgb [h, w, 3], depth [h, w], opacity [h, w])``,
        float32, colour composited on ``background``, z-depth in metres (0 where nothing is
        seen); the same numbers as ``nerfsv render`` for the same camera."""
        ...
    def density(self, points: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Density σ (1/m) at world points ``[n, 3]`` (metres): ``[n]`` float32, 0 outside the
        box."""
        ...
    def uncertainty(
        self, method: str, pose: npt.ArrayLike, width: int, height: int, intrinsics: _Intrinsics,
        image: npt.ArrayLike, config: Optional[_Path] = ..., overrides: Optional[List[str]] = ...,
    ) -> Optional[Dict[str, Any]]:
        """The paper's uncertainty of one image (``"ga"`` or ``"bla"``; ``image`` ``[h, w, 4]``
        RGBA or ``[h, w, 3]`` RGB in ``[0, 1]``): the figures as a dict, ``None`` when every ray
        misses the model."""
        ...
    def state_dict(self, optimizer: bool = ...) -> Dict[str, npt.NDArray[np.float32]]:
        """The checkpoint's tensors under their torch-ngp names, float32 in the file's shapes:
        ``encoder.embeddings`` ``[n_entries, 2]``, ``sigma_net.{0,1}.weight`` and
        ``color_net.{0,1,2}.weight`` ``[out, in]`` (no biases), ``density_grid``
        ``[res, res, res]`` (``[z][y][x]``); with ``optimizer`` also the Adam moments
        ``optimizer.exp_avg.NAME`` and ``optimizer.exp_avg_sq.NAME``."""
        ...
    def collision_field(
        self, scene: str = ..., mesh: Optional[_Path] = ..., cells_per_metre: float = ...
    ) -> Dict[str, Any]:
        """The model's signed collision field on the grid of a ground truth (a built-in
        ``scene`` or a ``mesh`` file) at ``cells_per_metre``: ``values`` ``[nz, ny, nx]``
        float32 (metres, negative inside), ``origin`` (metres), ``cell`` (metres), ``dims``
        ``(nx, ny, nz)``."""
        ...

def load_dataset(path: _Path, split: str = ..., downscale: int = ..., depth: bool = ...) -> Dict[str, Any]: ...
def write_png(path: _Path, rgb: npt.ArrayLike) -> None: ...
def write_depth_png(path: _Path, depth: npt.ArrayLike, opacity: npt.ArrayLike) -> None: ...
def train(
    data: _Path, out: _Path, steps: Optional[int] = ..., seconds: Optional[float] = ..., config: Optional[_Path] = ...,
    seed: Optional[int] = ..., resume: bool = ..., progress: Optional[Callable[[Dict[str, float]], Any]] = ...,
    overrides: Optional[List[str]] = ...,
) -> Model: ...
def ground_truth_field(scene: str = ..., mesh: Optional[_Path] = ..., cells_per_metre: float = ...) -> Dict[str, Any]: ...
def load_field(path: _Path) -> Dict[str, Any]: ...
def render_dataset(
    out: _Path, scene: str = ..., mesh: Optional[_Path] = ..., width: Optional[int] = ..., height: Optional[int] = ...,
    train: Optional[int] = ..., val: Optional[int] = ..., test: Optional[int] = ..., fov: Optional[float] = ...,
    close_up: Optional[float] = ..., supersample: Optional[int] = ..., seed: Optional[int] = ...,
) -> str: ...
def render_view(
    pose: npt.ArrayLike, width: int, height: int, intrinsics: _Intrinsics, scene: str = ...,
    mesh: Optional[_Path] = ..., supersample: int = ...,
) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]: ...
def uncertainty_offline(
    model: Model, data: _Path, method: str = ..., max_images: Optional[int] = ..., rays: Optional[int] = ...,
    downscale: int = ..., config: Optional[_Path] = ..., overrides: Optional[List[str]] = ...,
) -> Tuple[Dict[str, Any], str]: ...
def uncertainty_ause(
    model: Model, data: _Path, method: str = ..., split: str = ..., max_images: Optional[int] = ...,
    config: Optional[_Path] = ..., overrides: Optional[List[str]] = ...,
) -> str: ...
def uncertainty_maps(
    model: Model, method: str, pose: npt.ArrayLike, width: int, height: int, intrinsics: _Intrinsics,
    image: npt.ArrayLike, depth: Optional[npt.ArrayLike] = ..., config: Optional[_Path] = ...,
    overrides: Optional[List[str]] = ...,
) -> Dict[str, Any]: ...
def fly(
    model: Union[_Path, Model], world: str = ..., estimator: str = ..., disturbances: Optional[npt.NDArray[np.float64]] = ...,
    random_seed: Optional[int] = ..., seed: Optional[int] = ..., config: Optional[_Path] = ..., scene: str = ...,
    mesh: Optional[_Path] = ..., nerf_field: Optional[_Path] = ..., overrides: Optional[List[str]] = ...,
) -> Dict[str, Any]: ...
def stress(
    model: Union[_Path, Model], out: _Path, sampler: str = ..., world: str = ..., estimator: str = ..., replay: bool = ...,
    seed: Optional[int] = ..., config: Optional[_Path] = ..., scene: str = ..., mesh: Optional[_Path] = ...,
    nerf_field: Optional[_Path] = ..., resume: bool = ...,
    executor: Optional[Callable[[str, str, List[bytes]], Iterable[Tuple[int, bytes]]]] = ...,
    overrides: Optional[List[str]] = ..., reward: Optional[str] = ..., measure: Optional[str] = ...,
    uncertainty: str = ..., field: Optional[_Path] = ...,
) -> str: ...
def stress_system(system: Any, sampler: str, settings: Dict[str, Any]) -> Dict[str, Any]:
    """``settings``: every one of ``std`` (``[dim]`` list or None), ``seed``, ``config``,
    ``overrides`` (list), ``out``, ``resume`` (bool), ``proposal_mean``, ``proposal_std``
    (``[steps, dim]`` float64 arrays or None)."""
    ...
def stress_context(
    model: _Path, seed: Optional[int] = ..., config: Optional[_Path] = ..., scene: str = ...,
    mesh: Optional[_Path] = ..., nerf_field: Optional[_Path] = ..., overrides: Optional[List[str]] = ...,
) -> bytes: ...
def run_jobs(context: bytes, world: str, estimator: str, jobs: List[bytes], threads: int = ...) -> List[bytes]: ...
