"""The latent-texture model a texture set gets when no model is named (`neumat fit SET`): at the recommended
preset on a CPU, the gated model where the set has normal detail or metal, tripleplane on a flat dielectric;
elsewhere the gated model (the paper's Table 6, at its budget).

On a flat dielectric the filtered appearance is close to an average of albedos, the regime where concatenated
spatial and directional features (tripleplane) are enough; on issue 55's selection-free crops at the CPU recipe
tripleplane is ahead exactly there (NOTES.md, "model a texture set gets"). The rule was measured only there, so
other presets and devices keep the paper's choice.
"""
from __future__ import annotations

from neumat.fit.preset import DEFAULT_PRESET
from neumat.io.texture_set import TextureSet
from neumat.reflectance.texture_statistics import normal_tilt_deg

#: mean normal-map tilt (degrees) below which a set counts as flat
FLAT_TILT_DEG = 5.0
#: mean metalness below which a set counts as a dielectric
DIELECTRIC_METALNESS = 0.5


def model_for_texture_set(textures: TextureSet, preset: str = DEFAULT_PRESET, device_type: str = "cpu"
                          ) -> tuple[str, str]:
    """(model name, the reason in a few words) for `textures` fitted with `preset` on a `device_type` device
    (module docstring)."""
    if preset != DEFAULT_PRESET or device_type != "cpu":
        return "multiscale", ("the paper's model for texture sets (the choice by texture statistics was measured "
                              f"only with the {DEFAULT_PRESET} preset on a CPU)")
    tilt = float(normal_tilt_deg(textures).mean())
    metal = float(textures.metalness.float().mean())
    stats = f"mean normal tilt {tilt:.1f} deg, metalness {metal:.2f}"
    if tilt < FLAT_TILT_DEG and metal < DIELECTRIC_METALNESS:
        return "tripleplane", (f"a flat dielectric ({stats}; tilt < {FLAT_TILT_DEG:g} and metalness < "
                               f"{DIELECTRIC_METALNESS:g}), where tripleplane was measured ahead of the gated model")
    return "multiscale", (f"normal detail or metal ({stats}), where the gated model was measured ahead of "
                          "tripleplane")
