"""The latent-texture model a texture set gets when no model is named (`neumat fit SET`): at the recommended
preset on a CPU, tripleplane on a flat, rough dielectric; elsewhere (normal detail, metal, or a near-mirror) the
gated model on a small source and NeuMIP on a large one; other presets and devices the gated model (the paper's
Table 6, at its budget).

On a flat dielectric the filtered appearance is close to an average of the texels' BRDFs, a diffuse colour under a
specular lobe that hardly varies: concatenated spatial and directional features (tripleplane) are enough. On a metal
the texels' colours tint the specular lobe itself, a product of spatial and directional variation that the gated
model's product of latent and angular features holds; a near-mirror keeps the gated model too, whose gated angular
textures hold the sharp lobe. That holds where each texel's latent sees thousands of the CPU recipe's queries (issue
55's selection-free 64^2 crops, where the thresholds come from: NOTES.md, "model a texture set gets"). On a whole
1K set a texel sees about 16, and the gated model, which multiplies everything it decodes by its latent, falls
behind: there NeuMIP (its 8000-step default) scores best on the sets with normal detail or metal (the gated model
1.1-2.3x its FLIP), tripleplane on the flat, rough dielectric (the multiscale benchmark suite's full run, confirmed
on procedural 1K sets; NOTES.md).
"""
from __future__ import annotations

import math

from neumat.fit.preset import DEFAULT_PRESET
from neumat.io.texture_set import TextureSet
from neumat.reflectance.texture_statistics import normal_tilt_deg

#: mean normal-map tilt (degrees) below which a set counts as flat (measured: tripleplane ahead up to 2.5, the
#: gated model from 3.3 except the brushed metal at 4.3)
FLAT_TILT_DEG = 3.0
#: mean perceptual roughness below which a flat set counts as a near-mirror (measured: 0.09 gated, 0.48 tripleplane)
MIRROR_ROUGHNESS = 0.2
#: mean metalness from which a flat set counts as a metal (measured at the std-0.1 default, session 64: the flat
#: metal Metal027, metalness 1, to the gated model on 8 of 8 (crop, seed) pairs; the flat dielectric Wood092,
#: metalness 0, to tripleplane on 8 of 8)
METAL = 0.5
#: texels above which a source counts as large (NeuMIP instead of the gated model): 2 x 256^2 (about 362^2), the
#: geometric midpoint of the sizes measured on either side (session 76): at 256^2 the gated model's FLIP is 0.99x
#: NeuMIP's on average over four procedural sets (0.79-1.06x), at 512^2 1.13x (1.01-1.36x) and on two held-out
#: shared-set crops at two seeds 1.03-1.44x; on whole 1K sets of 600 x 1024 texels and more 1.1-2.3x (session 75)
LARGE_SOURCE_TEXELS = 2 * 256 * 256


def model_for_texture_set(textures: TextureSet, preset: str = DEFAULT_PRESET, device_type: str = "cpu"
                          ) -> tuple[str, str]:
    """(model name, the reason in a few words) for `textures` fitted with `preset` on a `device_type` device
    (module docstring)."""
    if preset != DEFAULT_PRESET or device_type != "cpu":
        return "multiscale", ("the paper's model for texture sets (the choice by texture statistics was measured "
                              f"only with the {DEFAULT_PRESET} preset on a CPU)")
    tilt = float(normal_tilt_deg(textures).mean())
    rough = float(textures.roughness.float().mean())
    metal = float(textures.metalness.float().mean())
    h, w = textures.roughness.shape
    stats = f"{h} x {w} texels, mean normal tilt {tilt:.1f} deg, roughness {rough:.2f}, metalness {metal:.2f}"
    if tilt < FLAT_TILT_DEG and rough >= MIRROR_ROUGHNESS and metal < METAL:
        return "tripleplane", (f"a flat, rough dielectric ({stats}; tilt < {FLAT_TILT_DEG:g}, roughness >= "
                               f"{MIRROR_ROUGHNESS:g}, metalness < {METAL:g}), where tripleplane was measured ahead "
                               "of the other latent models")
    if h * w > LARGE_SOURCE_TEXELS:
        return "neumip", (f"a large source with normal detail, metal or a near-mirror ({stats}; more than "
                          f"{LARGE_SOURCE_TEXELS} texels, about {math.isqrt(LARGE_SOURCE_TEXELS)}^2), where NeuMIP "
                          "was measured ahead of the gated model and tripleplane: the CPU recipe's queries are too "
                          "few a texel for the gated model")
    return "multiscale", (f"normal detail, metal or a near-mirror on a small source ({stats}), where the gated model "
                          "was measured ahead of tripleplane")
