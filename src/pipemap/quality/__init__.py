"""A result is right or says why not: too little to map is refused, and every section is rated
good / suspect / failed from the run's own figures (no ground truth).

    verdict          checks, section and run ratings, the one-line verdict
    mappable         frames too dark, blank, frozen or few to map
    network_checks   the network pipeline's sections
    straight_checks  the straight-pipe methods (dense, sparse-cylinder)
"""

from pipemap.quality.mappable import FrameStats, require_mappable
from pipemap.quality.network_checks import free_radius, network_verdict
from pipemap.quality.straight_checks import motion_slips, straight_verdict
from pipemap.quality.verdict import FAILED, GOOD, SUSPECT, Check, RunVerdict, SectionVerdict

__all__ = ["FAILED", "GOOD", "SUSPECT", "Check", "FrameStats", "RunVerdict", "SectionVerdict", "free_radius",
           "motion_slips", "network_verdict", "require_mappable", "straight_verdict"]
