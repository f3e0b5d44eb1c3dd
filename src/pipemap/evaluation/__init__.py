"""Metrics against ground truth: trajectory error (ATE, path length), the 2010 report's
distance travelled (Table 2) and the fisheye paper's junction distances (Table I).

Reads result files only; never imports the estimators that produced them.
"""

from pipemap.evaluation.align import Alignment, umeyama
from pipemap.evaluation.evaluate import (
    EstimatedJunction,
    EvaluationResult,
    evaluate,
    read_junction_list,
    read_junctions,
    write_metrics,
)
from pipemap.evaluation.metrics import (
    AteResult,
    DistanceRow,
    DistanceTravelled,
    ElbowRow,
    JunctionPair,
    JunctionTable,
    associate,
    ate,
    distance_travelled,
    junction_table,
    path_length,
    principal_axis,
)
from pipemap.evaluation.tables import print_tables, tables

__all__ = [
    "Alignment",
    "AteResult",
    "ElbowRow",
    "EstimatedJunction",
    "DistanceRow",
    "DistanceTravelled",
    "EvaluationResult",
    "JunctionPair",
    "JunctionTable",
    "associate",
    "ate",
    "distance_travelled",
    "evaluate",
    "junction_table",
    "path_length",
    "principal_axis",
    "print_tables",
    "read_junction_list",
    "read_junctions",
    "tables",
    "umeyama",
    "write_metrics",
]
