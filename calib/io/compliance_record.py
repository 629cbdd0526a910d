"""Joint terms as read from a compliance sidecar or a JSON report (:class:`ComplianceRecord`,
made by :func:`calib.io.compliance_file.read_compliance`), in a module of its own: loaded when a
record is read, not by every ``calib calibrate`` (which names the sidecar beside its URDF; a
dataclass costs ~3M instructions to build at import)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np


if TYPE_CHECKING:
    from calib.model.compliance import Payload


@dataclass(frozen=True, eq=False)     # (array fields: compared by identity; nothing compares them)
class ComplianceRecord:
    """Joint terms read from a sidecar or a JSON report: compliance ``values`` (n,) SI, in joint
    order (None when the record has none), the joint names, the payload and gravity of the
    calibration (None / (3,) m/s^2, None without compliance), and ``periodic``: the periodic
    coefficients by name (rad; None without them)."""

    joints: tuple[str, ...]
    values: np.ndarray | None
    payload: Payload | None
    gravity: np.ndarray | None
    periodic: dict[str, float] | None = None
