"""Plots of a Material's BRDF: the (theta_h, theta_d) slice and in-plane polar curves, on a log scale.

Rendered with matplotlib's Agg canvas (no global backend change) and returned as uint8 (H, W, 3).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..core.coords import rusinkiewicz_to_io
from ..core.errors import InputError
from ..core.material import Material, material_device
from ..core.query import Query
from ..color.tonemap import LUMINANCE


def brdf_slice_image(material: Material, resolution: int = 90, channels: str = "rgb", decades: float = 5.0,
                     uv: tuple[float, float] = (0.5, 0.5), device=None,
                     value_range: tuple[float, float] | None = None) -> np.ndarray:
    """Image (H, W, 3) uint8 of the BRDF on the (theta_h, theta_d) plane at phi_d = 90 deg (phi_h = 0).

    theta_h (x axis) and theta_d (y axis) take `resolution` cell centres in [0, 90] deg. One panel per
    channel (`channels` = "rgb") or one luminance panel ("luminance"), colour on a log scale spanning
    `decades` decades below the maximum; zero values and configurations below the horizon are grey.
    `value_range` (vmin, vmax), 0 < vmin < vmax, fixes one colour scale for every panel instead (to compare
    slices of several materials by eye; `brdf_slice_range` gives one). `uv` is used for spatially varying
    materials.
    """
    from matplotlib.colors import LogNorm

    if channels not in ("rgb", "luminance"):
        raise InputError(f"brdf_slice_image: channels must be 'rgb' or 'luminance', got {channels!r}")
    if int(resolution) != resolution or resolution < 2:
        raise InputError(f"brdf_slice_image: resolution must be an integer >= 2, got {resolution}")
    if value_range is not None and not (len(value_range) == 2 and 0 < value_range[0] < value_range[1]):
        raise InputError(f"brdf_slice_image: value_range must be (vmin, vmax) with 0 < vmin < vmax, got {value_range}")
    f = _slice_values(material, resolution, uv, device)
    planes = {"red": f[:, 0], "green": f[:, 1], "blue": f[:, 2]} if channels == "rgb" else {"luminance": f @ LUMINANCE}
    fig, canvas = _figure(4.2 * len(planes), 3.8)
    for k, (name, plane) in enumerate(planes.items()):
        ax = fig.add_subplot(1, len(planes), k + 1)
        if value_range is None:
            vmax = np.nanmax(plane, initial=0.0)
            vmax = vmax if vmax > 0 else 1.0
            vmin = vmax * 10.0 ** -decades
        else:
            vmin, vmax = value_range
        shown = np.ma.masked_where(~(plane > 0), plane).reshape(resolution, resolution)
        im = ax.imshow(shown, origin="lower", extent=(0, 90, 0, 90), cmap=_cmap("viridis"),
                       norm=LogNorm(vmin=vmin, vmax=vmax, clip=True), interpolation="nearest")
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        ax.set_xlabel("theta_h (deg)")
        ax.set_ylabel("theta_d (deg)")
        ax.set_title(name)
    fig.suptitle(f"{material.describe()}: BRDF slice, phi_d = 90 deg")
    fig.tight_layout()
    return _to_array(fig, canvas)


def brdf_slice_range(materials, decades: float = 4.0, resolution: int = 90, uv: tuple[float, float] = (0.5, 0.5),
                     device=None) -> tuple[float, float]:
    """One colour scale (vmin, vmax) for `brdf_slice_image` of several materials: vmax the largest value of
    any channel of any of their slices, vmin `decades` decades below."""
    top = max((np.nanmax(_slice_values(m, resolution, uv, device), initial=0.0) for m in materials), default=0.0)
    top = top if top > 0 else 1.0
    return top * 10.0 ** -decades, top


def _slice_values(material: Material, resolution: int, uv, device) -> np.ndarray:
    """BRDF (resolution^2, 3) on the slice's cell centres (theta_d rows, theta_h columns); NaN below the horizon."""
    centres = (torch.arange(resolution, dtype=torch.float64) + 0.5) * (math.pi / 2) / resolution
    theta_d, theta_h = torch.meshgrid(centres, centres, indexing="ij")
    theta_h, theta_d = theta_h.reshape(-1), theta_d.reshape(-1)
    wi, wo = rusinkiewicz_to_io(theta_h, torch.zeros_like(theta_h), theta_d, torch.full_like(theta_d, math.pi / 2))
    f = _evaluate(material, wi, wo, uv, device)
    f[(wi[:, 2] <= 0).numpy() | (wo[:, 2] <= 0).numpy()] = np.nan
    return f


def polar_plot(materials: dict[str, Material], theta_i_deg=(15, 45, 75), resolution: int = 181,
               decades: int = 4, uv: tuple[float, float] = (0.5, 0.5), device=None) -> np.ndarray:
    """Image (H, W, 3) uint8 of in-plane BRDF luminance curves, one polar panel per incident angle (two
    panels a row, each a half disc about 5 inches across at 100 dpi).

    wi lies in the x-z plane at -theta_i (phi = 180 deg); wo sweeps the same plane, theta_o from -90 to
    90 deg (mirror direction at +theta_i). Radius: log10 of the luminance over `decades` decades, from
    10^(e - decades) to 10^e, e = ceil(log10(largest value)). One curve per material (name -> Material).
    """
    if not materials:
        raise InputError("polar_plot: `materials` is empty")
    if int(decades) != decades or decades < 1:
        raise InputError(f"polar_plot: decades must be a positive integer, got {decades}")
    decades = int(decades)
    if not theta_i_deg or any(not 0 <= t < 90 for t in theta_i_deg):
        raise InputError(f"polar_plot: theta_i_deg must be angles in [0, 90), got {theta_i_deg}")
    theta_o = torch.linspace(-math.pi / 2, math.pi / 2, resolution, dtype=torch.float64)
    wo = torch.stack([torch.sin(theta_o), torch.zeros_like(theta_o), torch.cos(theta_o)], -1)
    curves = {}
    for t in theta_i_deg:
        ti = math.radians(t)
        wi = torch.tensor([[-math.sin(ti), 0.0, math.cos(ti)]], dtype=torch.float64).expand(resolution, 3)
        for name, material in materials.items():
            curves[t, name] = _evaluate(material, wi, wo, uv, device) @ LUMINANCE
    top = max((np.nanmax(c, initial=0.0) for c in curves.values()), default=0.0)
    floor = math.ceil(np.log10(top)) - decades if top > 0 else -decades
    columns = min(len(theta_i_deg), 2)
    rows = math.ceil(len(theta_i_deg) / columns)
    # a half-disc polar axes reserves its full square: square cells, the blank lower halves trimmed afterwards
    fig, canvas = _figure(6.0 * columns, 6.0 * rows + 0.6)
    for k, t in enumerate(theta_i_deg):
        ax = fig.add_subplot(rows, columns, k + 1, projection="polar")
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)
        ax.set_thetamin(-90)
        ax.set_thetamax(90)
        for name in materials:
            r = np.log10(np.maximum(curves[t, name], 1e-300)) - floor
            ax.plot(theta_o.numpy(), np.maximum(r, 0.0), label=str(name), linewidth=1.6)
        ax.axvline(math.radians(-t), color="grey", linestyle="--", linewidth=0.8)
        ax.set_ylim(0, decades)
        ax.set_yticks(range(decades + 1))
        ax.set_yticklabels([])
        ax.tick_params(labelsize=10)
        for d in range(1, decades + 1):
            ax.text(math.radians(2), d, f"1e{floor + d}", fontsize=9, color="dimgrey", va="bottom")
        ax.set_title(f"theta_i = {t} deg (dashed: wi)", fontsize=12)
    fig.suptitle("in-plane BRDF luminance, log scale", fontsize=13)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.legend(*fig.axes[0].get_legend_handles_labels(), loc="lower center", ncol=min(len(materials), 6),
               fontsize=11, frameon=False)
    return _trim_blank_rows(_to_array(fig, canvas))


def _evaluate(material: Material, wi: torch.Tensor, wo: torch.Tensor, uv, device) -> np.ndarray:
    """material.eval at float64 directions (N, 3) -> float64 numpy (N, 3)."""
    device = torch.device(device) if device is not None else material_device(material)
    n = wi.shape[0]
    uv_t = torch.tensor(uv, dtype=torch.float32).expand(n, 2) if material.spatially_varying else None
    q = Query(wi.to(torch.float32), wo.to(torch.float32), uv=uv_t).to(device)
    with torch.no_grad():
        f = material.eval(q)
    if tuple(f.shape) != (n, 3):
        raise InputError(f"{material.describe()}.eval returned shape {tuple(f.shape)}, expected ({n}, 3)")
    return f.detach().to("cpu", torch.float64).numpy().copy()


def _cmap(name: str):
    """The named colour map with grey for masked (zero or invalid) values."""
    from matplotlib import colormaps

    return colormaps[name].with_extremes(bad=(0.6, 0.6, 0.6))


def _figure(width: float, height: float):
    """A matplotlib Figure on its own Agg canvas (no pyplot state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    return fig, FigureCanvasAgg(fig)


def _trim_blank_rows(img: np.ndarray, keep: int = 24) -> np.ndarray:
    """img (H, W, 3) with every run of more than `keep` all-white rows shortened to `keep` rows."""
    blank = (img == 255).all(axis=(1, 2))
    rows, run = [], 0
    for y, b in enumerate(blank):
        run = run + 1 if b else 0
        if run <= keep:
            rows.append(y)
    return img[rows]


def _to_array(fig, canvas) -> np.ndarray:
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
