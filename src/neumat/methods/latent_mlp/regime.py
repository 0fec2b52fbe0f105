"""The latent-texture model a texture set gets when no model is named (`neumat fit SET`): at the recommended
preset on a CPU, tripleplane on a flat, rough dielectric, the gated model elsewhere (normal detail, metal, or a
near-mirror); other presets and devices the gated model (the paper's Table 6, at its budget).

On a flat dielectric the filtered appearance is close to an average of the texels' BRDFs, a diffuse colour under a
specular lobe that hardly varies: concatenated spatial and directional features (tripleplane) are enough. On a metal
the texels' colours tint the specular lobe itself, a product of spatial and directional variation that the gated
model's product of latent and angular features holds; a near-mirror keeps the gated model too, whose gated angular
textures hold the sharp lobe. The thresholds come from issue 55's selection-free 64^2 crops at the recommended
preset's CPU recipe (NOTES.md, "model a texture set gets"). The source's size does not enter: at the recipe's
initial latent scale (std 0.1) the larger sources measured split as the crops do (selection_free.md, "The latents'
initial scale").
"""
from __future__ import annotations

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
    stats = f"mean normal tilt {tilt:.1f} deg, roughness {rough:.2f}, metalness {metal:.2f}"
    if tilt < FLAT_TILT_DEG and rough >= MIRROR_ROUGHNESS and metal < METAL:
        return "tripleplane", (f"a flat, rough dielectric ({stats}; tilt < {FLAT_TILT_DEG:g}, roughness >= "
                               f"{MIRROR_ROUGHNESS:g}, metalness < {METAL:g}), where tripleplane was measured ahead "
                               "of the gated model")
    return "multiscale", (f"normal detail, metal or a near-mirror ({stats}), where the gated model was measured "
                          "ahead of tripleplane")
