"""Neural path guiding for renderers: the Python face of the Rust library ``guiding``.

``Field`` learns, online, where light comes from; ``BatchRecorder`` turns a wavefront of
paths into its training samples; ``Schedule`` says when to train. ``import guiding.mitsuba``
registers the Mitsuba 3 integrator ``guided_path``.
"""

from ._guiding import (  # noqa: F401
    BatchRecorder,
    DistributionBatch,
    Field,
    FieldStats,
    GuideCache,
    GuidingError,
    Schedule,
    ScheduleReport,
    UpdateReport,
    __version__,
)

__all__ = [
    "BatchRecorder",
    "DistributionBatch",
    "Field",
    "FieldStats",
    "GuideCache",
    "GuidingError",
    "Schedule",
    "ScheduleReport",
    "UpdateReport",
    "__version__",
]
