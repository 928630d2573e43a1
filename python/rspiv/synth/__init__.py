"""Synthetic data whose ground truth we control: calibration targets, particle image pairs and
boundary-layer campaigns. Python describes the scene; Rust renders the pixels.
"""

from rspiv.synth.particles import convected_sequence, particle_pair, particle_sequence
from rspiv.synth.target import (
    PAPER_OPTICS,
    CalibrationTarget,
    LensDistortion,
    Optics,
    calibration_target,
    paper_lens,
)
from rspiv.synth.tbl import TBLFlow, TBLTruth, tbl_pair, tbl_scene

__all__: list[str] = []
__all__ += [
    "PAPER_OPTICS",
    "Optics",
    "LensDistortion",
    "paper_lens",
    "CalibrationTarget",
    "calibration_target",
]
__all__ += ["convected_sequence", "particle_pair", "particle_sequence"]
__all__ += ["TBLFlow", "TBLTruth", "tbl_pair", "tbl_scene"]
