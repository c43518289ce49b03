"""Type stubs of the extension module (``guiding-py/src``)."""

from os import PathLike
from typing import List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

F32 = npt.NDArray[np.float32]
U32 = npt.NDArray[np.uint32]

class GuidingError(Exception): ...

class UpdateReport:
    steps: int
    skipped_steps: int
    mean_loss: float
    buffered_samples: int
    batch_size: int
    converged: bool

class FieldStats:
    steps: int
    skipped_steps: int
    generation: int
    accepted_samples: int
    ignored_samples: int
    rejected_samples: int
    converged: bool
    overflowed_samples: int
    buffered_samples: int
    param_count: int

class ScheduleReport:
    traced_seconds: float
    trained_seconds: float
    steps: int
    updates: int
    seconds_per_step: float
    training_share: float

class SelectionReport:
    samples_used: int
    cells_fitted: int
    cells_global: int
    cells_off: int
    global_selection: float
    mean: float
    variance_ratio: float

class GroupWeight:
    group: int
    passes: int
    relative_variance: Tuple[float, float]
    pass_weight: Tuple[float, float]
    share: float

class Combination:
    groups: List[GroupWeight]
    predicted_gain: float
    fell_back: bool
    pixels: F32
    var_of_mean: F32

class PassCombiner:
    def __init__(self, width: int, height: int, epsilon: float = 0.01, smoothing_radius: int = 2,
                 cap_at_largest_group: bool = True) -> None: ...
    def add_pass(self, group: int, pixels: F32) -> None: ...
    @property
    def passes(self) -> int: ...
    @property
    def group_count(self) -> int: ...
    def combine(self) -> Combination: ...

class DistributionBatch:
    def __len__(self) -> int: ...
    def selection_probability(self) -> F32: ...

class GuideCache:
    @property
    def cells(self) -> int: ...
    @property
    def misses(self) -> U32: ...
    def decode(self, field: "Field", position: F32, jitter: F32) -> DistributionBatch: ...
    def extend(self, field: "Field", position: F32) -> int: ...
    def refresh(self, field: "Field") -> None: ...
    def vmf_table(self) -> Optional[dict]: ...
    def fit_selection(
        self, field: "Field", recorder: "BatchRecorder", guide_cost: float = 0.0
    ) -> SelectionReport: ...

class Field:
    def __init__(
        self,
        bounds_min: Sequence[float],
        bounds_max: Sequence[float],
        representation: str = "npm",
        target: str = "radiance",
        size: str = "compact",
        threads: int = 0,
        selection_probability: Optional[float] = None,
    ) -> None: ...
    @staticmethod
    def load(path: Union[str, PathLike]) -> "Field": ...
    def save(self, path: Union[str, PathLike]) -> None: ...
    @property
    def representation(self) -> str: ...
    @property
    def target(self) -> str: ...
    @property
    def size(self) -> str: ...
    @property
    def generation(self) -> int: ...
    def stats(self) -> FieldStats: ...
    def decode(
        self,
        position: F32,
        normal: Optional[F32] = None,
        wo: Optional[F32] = None,
        roughness: Optional[F32] = None,
    ) -> DistributionBatch: ...
    def sample(self, batch: DistributionBatch, lanes: U32, u: F32) -> Tuple[F32, F32]: ...
    def pdf(self, batch: DistributionBatch, lanes: U32, directions: F32) -> F32: ...
    def update(self) -> UpdateReport: ...
    def train_scheduled(self, schedule: "Schedule") -> UpdateReport: ...
    def stop_training(self) -> None: ...
    def build_cache(self, position: F32, resolution: int = 64) -> GuideCache: ...

class BatchRecorder:
    def __init__(self) -> None: ...
    def start(self, n: int) -> None: ...
    def add_vertices(
        self,
        slots: U32,
        position: F32,
        normal: F32,
        wo: F32,
        roughness: F32,
        emitted: F32,
        emitted_mis_weight: F32,
        is_delta: npt.NDArray[np.bool_],
    ) -> None: ...
    def add_direct(self, slots: U32, rgb: F32) -> None: ...
    def set_continuations(
        self, slots: U32, wi: F32, sample_pdf: F32, bsdf_pdf: F32, bsdf_cos: F32
    ) -> None: ...
    def scale_continuations(self, slots: U32, factor: F32) -> None: ...
    def add_escaped_radiance(self, slots: U32, rgb: F32, mis: F32) -> None: ...
    def end(self) -> F32: ...
    def flush_into(self, field: Field, keep: bool = False) -> int: ...
    @property
    def kept_samples(self) -> int: ...
    def __len__(self) -> int: ...
    @property
    def ignored_calls(self) -> int: ...

class Schedule:
    def __init__(
        self,
        spp: Optional[int] = None,
        seconds: Optional[float] = None,
        train_fraction: Optional[float] = None,
        training_share: Optional[float] = None,
    ) -> None: ...
    def in_training_phase(self, elapsed: float, pass_index: int) -> bool: ...
    def end_training(self) -> None: ...
    @property
    def training_over(self) -> bool: ...
    def record_traced(self, seconds: float, paths: int) -> None: ...
    def report(self) -> ScheduleReport: ...
