"""Sampling warps: triplets `sample_x(u) / x_pdf(...) / invert_x(...)` mapping [0, 1]^2 to domains."""
from .disk import concentric_disk_pdf, invert_concentric_disk, sample_concentric_disk
from .hemisphere import (cosine_hemisphere_pdf, invert_cosine_hemisphere, invert_uniform_hemisphere,
                         sample_cosine_hemisphere, sample_uniform_hemisphere, uniform_hemisphere_pdf)
from .microfacet_proxy import ProxyLobes, proxy_from_raw, proxy_pdf, sample_proxy
from .sphere import invert_uniform_sphere, sample_uniform_sphere, uniform_sphere_pdf
from .spherical_gaussian import invert_vmf, sample_vmf, vmf_pdf
from .tabulated2d import Tabulated2D

__all__ = [
    "sample_concentric_disk", "concentric_disk_pdf", "invert_concentric_disk",
    "sample_uniform_hemisphere", "uniform_hemisphere_pdf", "invert_uniform_hemisphere",
    "sample_cosine_hemisphere", "cosine_hemisphere_pdf", "invert_cosine_hemisphere",
    "sample_uniform_sphere", "uniform_sphere_pdf", "invert_uniform_sphere",
    "sample_vmf", "vmf_pdf", "invert_vmf",
    "Tabulated2D",
    "ProxyLobes", "proxy_from_raw", "sample_proxy", "proxy_pdf",
]

# --- GGX warps (owned by the GGX engineer): add `from .ggx import ...` here and extend __all__ ---
from .ggx import (ggx_reflection_pdf, ggx_vndf_pdf, invert_ggx_reflection, invert_ggx_vndf,  # noqa: E402
                  sample_ggx_reflection, sample_ggx_vndf)

__all__ += ["sample_ggx_vndf", "ggx_vndf_pdf", "invert_ggx_vndf",
            "sample_ggx_reflection", "ggx_reflection_pdf", "invert_ggx_reflection"]

# --- azimuthal-equidistant Gaussian lobe (NeuPreSS importance sampling) ---
from .azimuthal_gaussian import (azimuthal_gaussian_pdf, invert_azimuthal_gaussian,  # noqa: E402
                                 sample_azimuthal_gaussian)

__all__ += ["sample_azimuthal_gaussian", "azimuthal_gaussian_pdf", "invert_azimuthal_gaussian"]
