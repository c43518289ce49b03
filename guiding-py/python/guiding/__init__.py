"""Neural path guiding for renderers: the Python face of the Rust library ``guiding``.

``Field`` learns, online, where light comes from; ``BatchRecorder`` turns a wavefront of
paths into its training samples; ``Schedule`` says when to train; ``PassCombiner`` weights
a render's passes by their variance. ``import guiding.mitsuba`` registers the Mitsuba 3
integrator ``guided_path``.
"""

from ._guiding import (  # noqa: F401
    BatchRecorder,
    Combination,
    DistributionBatch,
    Field,
    FieldStats,
    GroupWeight,
    GuideCache,
    GuidingError,
    PassCombiner,
    Schedule,
    ScheduleReport,
    SelectionReport,
    UpdateReport,
    __version__,
)

__all__ = [
    "BatchRecorder",
    "Combination",
    "DistributionBatch",
    "Field",
    "FieldStats",
    "GroupWeight",
    "GuideCache",
    "GuidingError",
    "PassCombiner",
    "Schedule",
    "ScheduleReport",
    "SelectionReport",
    "UpdateReport",
    "__version__",
]
