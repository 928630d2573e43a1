"""Synthetic data whose ground truth we control: calibration targets, particle image pairs and
boundary-layer campaigns. Python describes the scene; Rust renders the pixels.
"""

__all__: list[str] = []
