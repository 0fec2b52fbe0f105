"""Pictures for humans: comparison strips, BRDF slices and polar plots, self-contained HTML reports."""
from .compare import compare_image
from .report import write_report
from .slices import brdf_slice_image, polar_plot

__all__ = ["compare_image", "brdf_slice_image", "polar_plot", "write_report"]
