"""File formats at the edge of calib: one CSV layer (:mod:`calib.formats.csv_layer`) read through
column specs, and the three file kinds as specs (:mod:`calib.formats.specs`): measurements, poses
to measure, compensation targets. The algorithm modules take arrays and models, never paths."""
from .csv_layer import ReadOptions, Spec, Table, read_table
from .specs import (CompensationTargets, read_measurements, read_poses, read_targets,
                    write_compensation, write_measurements, write_poses)

__all__ = ["ReadOptions", "Spec", "Table", "read_table", "CompensationTargets",
           "read_measurements", "write_measurements", "read_poses", "write_poses", "read_targets",
           "write_compensation"]
