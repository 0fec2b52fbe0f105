"""Colour: sRGB transfer functions, luminance weights and tone curves (below io and metrics)."""
