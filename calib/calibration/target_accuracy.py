"""The accuracy on the rows of each target of a multi-target calibration
(:class:`TargetAccuracy`), in a module of its own: loaded by the calibrations that have targets
only (a dataclass costs ~3M instructions to build at import)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING


if TYPE_CHECKING:
    from calib.calibration.accuracy import AccuracyStats


@dataclass(frozen=True, eq=False)     # (AccuracyStats fields, themselves compared by identity; nothing compares them)
class TargetAccuracy:
    """Accuracy on the rows of one target of a multi-target calibration (see
    :class:`AccuracyStats`): before / after on the calibration rows, and on the validation rows
    (None without validation data)."""

    target: str
    before: AccuracyStats = field(repr=False)
    after: AccuracyStats = field(repr=False)
    validation_before: AccuracyStats | None = field(default=None, repr=False)
    validation_after: AccuracyStats | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        return {"before": self.before.to_dict(), "after": self.after.to_dict(),
                "validation": None if self.validation_after is None else {
                    "before": self.validation_before.to_dict(), "after": self.validation_after.to_dict()}}
