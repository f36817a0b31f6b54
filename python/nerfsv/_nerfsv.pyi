"""Type stubs of the Rust extension module (see nerfsv/__init__.py for the documented API)."""

from os import PathLike
from typing import Any, Callable, Dict, Iterable, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, PathLike[str]]
_Intrinsics = Tuple[float, float, float, float]

__version__: str

class Model:
    @staticmethod
    def load(path: _Path) -> Model: ...
    @property
    def path(self) -> str: ...
    @property
    def aabb(self) -> Tuple[List[float], List[float]]: ...
    def render(
        self, pose: npt.ArrayLike, width: int, height: int, intrinsics: _Intrinsics,
        background: Tuple[float, float, float] = ...,
    ) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.float32]]: ...
    def density(self, points: npt.ArrayLike) -> npt.NDArray[np.float32]: ...
    def uncertainty(
        self, method: str, pose: npt.ArrayLike, width: int, height: int, intrinsics: _Intrinsics,
        image: npt.ArrayLike, config: Optional[_Path] = ..., overrides: Optional[List[str]] = ...,
    ) -> str: ...
    def state_dict(self, optimizer: bool = ...) -> Dict[str, npt.NDArray[np.float32]]: ...
    def collision_field(
        self, scene: str = ..., mesh: Optional[_Path] = ..., cells_per_metre: float = ...
    ) -> Dict[str, Any]: ...

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
