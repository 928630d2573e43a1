"""rspiv: large-sensor PIV with lens-distortion correction.

Coordinates (everywhere, unless a name says otherwise): pixel frame with x = column, y = row,
origin at the centre of the top-left pixel, y growing downward; displacements follow the same
axes. "Object px" is the dewarped image's pixel frame. Flow outputs use x streamwise and y
wall-normal from the wall, in metres and wall units.
"""

from rspiv._rspiv import __version__
from rspiv.boundary_layer import BoundaryLayerResult, analyse_profile
from rspiv.calibration import Calibration, calibrate, calibrate_points
from rspiv.campaign import Campaign
from rspiv.campaign_config import CampaignConfig, load_campaign_config
from rspiv.campaign_init import CampaignInit, init_campaign
from rspiv.compare import FieldComparison, compare_fields
from rspiv.compare_series import SeriesComparison, compare_series
from rspiv.conditional import ConditionalAccumulator
from rspiv.correction import correct_vectors, piv_vectors
from rspiv.dewarp import dewarp
from rspiv.ensemble import EnsembleAccumulator, EnsembleField
from rspiv.errors import (
    ConvergenceError,
    CorrelationWarning,
    InvalidInputError,
    ParticleSizeWarning,
    RspivError,
)
from rspiv.export import read_tecplot, write_tecplot
from rspiv.mapping import Mapping, fit_mapping
from rspiv.montecarlo import MonteCarloResult, monte_carlo
from rspiv.outlier_screen import ScreenBounds, screen_bounds
from rspiv.particle_size import particle_diameter
from rspiv.peak_locking import locking_amplitude
from rspiv.piv import PivField, piv, piv_at, window_response
from rspiv.pod import PodResult, pod
from rspiv.ptv import Particles, Tracks, detect_particles, track_particles
from rspiv.ptv_profile import SublayerFit, TrackProfile, WallLine, sublayer_fit
from rspiv.quadrant import QuadrantAccumulator, gaussian_quadrant
from rspiv.recording import RecordingCheck, check_recording
from rspiv.reference import load_dns
from rspiv.reference_comparison import ReferenceComparison, compare_reference
from rspiv.repeatability import Repeatability, repeatability
from rspiv.settings import PivSettings
from rspiv.spod import SpodResult, spod
from rspiv.stats import FieldAccumulator
from rspiv.temporal import TemporalAccumulator
from rspiv.two_point import TwoPointAccumulator
from rspiv.vector_files import VectorFile, read_vectors
from rspiv.vector_statistics import VectorStatistics, vector_statistics
from rspiv.vortices import find_vortices, fit_oseen
from rspiv.wall import Wall, find_wall
from rspiv.wall_table import WallTable, wall_table

__all__ = ["__version__", "RspivError", "InvalidInputError", "ConvergenceError"]
__all__ += ["CorrelationWarning", "ParticleSizeWarning"]
__all__ += ["FieldAccumulator", "CampaignConfig", "load_campaign_config", "analyse_profile"]
__all__ += ["BoundaryLayerResult", "load_dns"]
__all__ += ["Mapping", "fit_mapping"]
__all__ += ["PivField", "PivSettings", "piv", "piv_at", "window_response", "particle_diameter"]
__all__ += ["Calibration", "calibrate", "calibrate_points", "MonteCarloResult", "monte_carlo"]
__all__ += ["Campaign", "piv_vectors", "correct_vectors"]
__all__ += ["dewarp", "Wall", "find_wall"]
__all__ += ["WallTable", "wall_table"]
__all__ += ["read_tecplot", "write_tecplot"]
__all__ += ["EnsembleAccumulator", "EnsembleField", "TwoPointAccumulator"]
__all__ += ["QuadrantAccumulator", "gaussian_quadrant", "PodResult", "pod", "find_vortices"]
__all__ += ["fit_oseen"]
__all__ += ["Repeatability", "repeatability", "RecordingCheck", "check_recording"]
__all__ += ["locking_amplitude", "ScreenBounds", "screen_bounds", "ConditionalAccumulator"]
__all__ += ["TemporalAccumulator", "SpodResult", "spod"]
__all__ += ["VectorFile", "read_vectors", "FieldComparison", "compare_fields"]
__all__ += ["SeriesComparison", "compare_series"]
__all__ += ["VectorStatistics", "vector_statistics"]
__all__ += ["CampaignInit", "init_campaign", "ReferenceComparison", "compare_reference"]
__all__ += ["Particles", "Tracks", "detect_particles", "track_particles"]
__all__ += ["SublayerFit", "TrackProfile", "WallLine", "sublayer_fit"]
