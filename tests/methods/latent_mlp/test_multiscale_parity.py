"""The fast multi-scale model equals a slow, direct transcription of its maths (outputs and gradients).

`_reference_latents` below is the implementation before the speed-up (session 9), kept here only as a test
oracle: bilinear reads by `grid_sample` over circularly padded textures, trilinear lookups level by level,
one FFT per preconditioned texture with a freshly built kernel, channels-first gating, shading frames with
`Tensor.norm`. The fast code must agree to float64 rounding (1e-10) in float64 and to float32 rounding in
float32, for the gated model, tripleplane and the homogeneous variant, with footprints, lods and neither.
"""
from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from neumat.core.material import upper_hemisphere
from neumat.core.query import Query
from neumat.methods.latent_mlp.multiscale import MultiScale
from neumat.nn.angular_texture import disk_polar, half_difference
from neumat.nn.latent_texture import footprint_axes
from neumat.nn.preconditioner import preconditioner_kernel
from neumat.nn.radial_warp import warp_radius

SMALL = dict(spatial_size=16, spatial_channels=4, half_channels=4, diff_channels=4, angular_radial=6,
             angular_phi=10, hidden=8, max_probes=6)


# ------------------------------------------------------------------------------------- slow reference

def _precondition(raw, strength):
    if strength == 0:
        return raw
    h, w = raw.shape[-2:]
    k = preconditioner_kernel(h, w, strength, raw.dtype, raw.device)
    return torch.fft.irfft2(torch.fft.rfft2(raw) * k, s=(h, w))


def _bilinear(tex, uv):
    c, h, w = tex.shape
    uv = torch.remainder(uv.to(tex.dtype), 1.0)
    x, y = uv[:, 0] * w - 0.5, (1 - uv[:, 1]) * h - 0.5
    grid = torch.stack([(x + 1) * (2 / (w + 1)) - 1, (y + 1) * (2 / (h + 1)) - 1], -1)
    padded = F.pad(tex.unsqueeze(0), (1, 1, 1, 1), mode="circular")
    out = F.grid_sample(padded, grid.view(1, 1, -1, 2), mode="bilinear", padding_mode="border", align_corners=True)
    return out.view(c, -1).t()


def _trilinear(levels, uv, lod):
    lod = lod.clamp(0, len(levels) - 1)
    lo = lod.floor().long()
    t = (lod - lo).unsqueeze(-1).to(levels[0].dtype)
    out = uv.new_zeros(uv.shape[0], levels[0].shape[0], dtype=levels[0].dtype)
    for l, tex in enumerate(levels):
        w = torch.where((lo == l).unsqueeze(-1), 1 - t, 0.0) + torch.where((lo + 1 == l).unsqueeze(-1), t, 0.0)
        sel = (w[:, 0] > 0).nonzero().squeeze(-1)
        if sel.numel():
            out = out.index_add(0, sel, w[sel] * _bilinear(tex, uv[sel]))
    return out


def _filter_anisotropic(levels, uv, footprint, max_probes):
    _, h, w = levels[0].shape
    scale = torch.tensor([w, h], dtype=footprint.dtype)
    major, minor, axis = footprint_axes(footprint * scale.view(1, 2, 1) * scale.view(1, 1, 2))
    minor = minor.clamp(min=1e-12)
    n = torch.ceil(major / minor).clamp(1, max_probes)
    sigma = torch.maximum(minor, major / max_probes)
    lod = torch.log2((2 * sigma).clamp(min=1e-12))
    spacing = torch.sqrt((12 * (major ** 2 - sigma ** 2)).clamp(min=0) / (n * n - 1).clamp(min=1))
    k = torch.arange(max_probes, dtype=uv.dtype)
    offset = (k.unsqueeze(0) - (n.unsqueeze(-1) - 1) / 2) * spacing.unsqueeze(-1)
    delta = offset.unsqueeze(-1) * axis.unsqueeze(1) / scale
    rows, probe = (k.unsqueeze(0) < n.unsqueeze(-1)).nonzero(as_tuple=True)
    values = _trilinear(levels, uv[rows] + delta[rows, probe], lod[rows])
    out = uv.new_zeros(uv.shape[0], levels[0].shape[0], dtype=levels[0].dtype)
    return out.index_add(0, rows, values / n[rows].unsqueeze(-1).to(values.dtype))


def _angular_read(tex_module, r, phi):
    """Channels-first (C, N) read by grid_sample over the pole-fixed, circularly padded texture."""
    tex = _precondition(tex_module.raw, tex_module.precondition.strength)
    p = tex_module.angular
    rows = torch.cat([tex[:, :1, :1].expand(-1, 1, p), tex[:, 1:]], 1)
    tex = torch.cat([rows[:, :, -1:], rows, rows[:, :, :1]], 2)
    column = torch.remainder(phi.to(tex.dtype), tex_module.period) * (p / tex_module.period) + 0.5
    grid = torch.stack([column * (2 / (p + 1)) - 1, r.to(tex.dtype).clamp(0, 1) * 2 - 1], -1)
    out = F.grid_sample(tex.unsqueeze(0), grid.view(1, 1, -1, 2), mode="bilinear", padding_mode="border",
                        align_corners=True)
    return out.view(tex_module.channels, -1)


def _lift(w):
    xy = w[:, :2]
    return torch.cat([xy, (1 - (xy * xy).sum(-1)).clamp(min=1e-10).sqrt().unsqueeze(-1)], -1)


def _frame(frame, z, wi, wo):
    v = F.linear(z, frame.decode.weight * frame.weight_scale, frame.decode.bias)
    n = v[:, :3] / v[:, :3].norm(dim=-1, keepdim=True).clamp(min=1e-12)
    t = v[:, 3:] - (v[:, 3:] * n).sum(-1, keepdim=True) * n
    t = t / t.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    b = torch.cross(n, t, dim=-1)
    local = lambda w: torch.stack([(w * t).sum(-1), (w * b).sum(-1), (w * n).sum(-1)], -1)  # noqa: E731
    return _lift(local(wi)), _lift(local(wo))


def _warp(warp, r, z):
    p = warp.decode(z) if warp.latent_dim > 0 else warp.params
    return warp_radius(r, p[..., :warp.terms], p[..., warp.terms:])


def _reference_eval(m: MultiScale, q: Query) -> torch.Tensor:
    wi, wo, z_s = q.wi, q.wo, None
    if m.spatial is not None:
        levels = [_precondition(t, m.spatial.precondition.strength) for t in m.spatial.raw]
        if q.footprint is not None:
            z_s = _filter_anisotropic(levels, q.uv, q.footprint, m.spatial.max_probes)
        elif q.lod is not None:
            z_s = _trilinear(levels, q.uv, q.lod.to(q.uv.dtype))
        else:
            z_s = _bilinear(levels[0], q.uv)
    wi, wo = _frame(m.frame, z_s, wi, wo) if m.frame is not None else (_lift(wi), _lift(wo))
    h, d = half_difference(wi, wo)
    r_h, phi_h = disk_polar(h)
    r_d, phi_d = disk_polar(d, math.pi)
    if m.warp_h is not None:
        r_h, r_d = _warp(m.warp_h, r_h, z_s), _warp(m.warp_d, r_d, z_s)
    a_h, a_d = _angular_read(m.half_texture, r_h, phi_h), _angular_read(m.diff_texture, r_d, phi_d)
    if z_s is None or not m.cfg.gating:
        x = torch.cat([a_h.t(), a_d.t()] if z_s is None else [a_h.t(), a_d.t(), z_s], -1)
    else:
        z = z_s.t().unsqueeze(0)
        z_h = (a_h.view(m.cfg.half_channels, -1, len(z_s)) * z).sum(1)
        z_d = (a_d.view(m.cfg.diff_channels, -1, len(z_s)) * z).sum(1)
        x = torch.cat([z_h, z_d], 0).t()
    f = torch.exp(m.mlp(x))
    return torch.where(upper_hemisphere(q.wi, q.wo).unsqueeze(-1), f, torch.zeros_like(f))


# ------------------------------------------------------------------------------------------ helpers

def _queries(n, kind, dtype, seed=0):
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 9, generator=g, dtype=torch.float64)

    def direction(a, b):  # cosine-weighted, a few below the horizon
        r, phi = a.sqrt(), 2 * math.pi * b
        return torch.stack([r * torch.cos(phi), r * torch.sin(phi), (1 - a).clamp(min=0).sqrt()], -1)

    wi, wo = direction(u[:, 0], u[:, 1]), direction(u[:, 2], u[:, 3])
    wo[::17, 2] *= -1
    uv = u[:, 4:6] * 3 - 1  # outside [0, 1]^2 too: wrap tiling
    footprint = lod = None
    if kind == "footprint":  # from sub-texel to the whole texture, elongated up to 30x
        s = torch.exp2(-9 + 9 * u[:, 6])
        e = 1 + 29 * u[:, 7] ** 3
        c, si = torch.cos(math.pi * u[:, 8]), torch.sin(math.pi * u[:, 8])
        rot = torch.stack([torch.stack([c, -si], -1), torch.stack([si, c], -1)], -2)
        footprint = (s * s).view(-1, 1, 1) * (rot @ torch.diag_embed(torch.stack([e * e, torch.ones_like(e)], -1))
                                              @ rot.transpose(1, 2))
        footprint = 0.5 * (footprint + footprint.transpose(1, 2))
    elif kind == "lod":
        lod = u[:, 6] * 6 - 0.5
    cast = lambda t: None if t is None else t.to(dtype)  # noqa: E731
    return Query(cast(wi), cast(wo), uv=cast(uv), footprint=cast(footprint), lod=cast(lod))


def _model(dtype, seed=0, **overrides):
    torch.manual_seed(seed)
    m = MultiScale(**{**SMALL, **overrides}).to(dtype)
    with torch.no_grad():  # leave the identity initialisation of frame, warps and MLP bias
        for p in m.parameters():
            p.add_(0.3 * torch.randn_like(p))
    return m


def _outputs_and_gradients(m, q, fn):
    out = fn(m, q)
    weight = torch.cos(torch.arange(out.numel(), dtype=out.dtype)).view_as(out)  # a generic linear functional
    grads = torch.autograd.grad((out * weight).sum(), list(m.parameters()), allow_unused=True)
    return out.detach(), [torch.zeros_like(p) if g is None else g for p, g in zip(m.parameters(), grads)]


CONFIGS = {"gated": {}, "tripleplane": dict(gating=False, radial_warps=False, shading_frame=False),
           "homogeneous": dict(homogeneous=True)}


# the homogeneous model has no spatial texture: point queries only
CASES = [(c, k) for c in sorted(CONFIGS) for k in ("footprint", "lod", "point") if c != "homogeneous" or k == "point"]


@pytest.mark.parametrize("config, kind", CASES)
def test_fast_model_equals_reference_in_float64(config, kind):
    m = _model(torch.float64, **CONFIGS[config])
    q = _queries(700, kind, torch.float64)
    out, grads = _outputs_and_gradients(m, q, MultiScale.eval)
    ref, ref_grads = _outputs_and_gradients(m, q, _reference_eval)
    assert bool((out > 0).any())
    torch.testing.assert_close(out, ref, rtol=1e-10, atol=1e-12)
    for (name, _), g, r in zip(m.named_parameters(), grads, ref_grads):
        torch.testing.assert_close(g, r, rtol=1e-10, atol=1e-10 * float(r.abs().max()) + 1e-14, msg=name)


@pytest.mark.parametrize("config", ["gated", "tripleplane"])
def test_fast_model_equals_reference_in_float32(config):
    """float32: differences are rounding only (relative 1e-5 on values, 1e-4 of the largest gradient)."""
    m = _model(torch.float32, seed=1, **CONFIGS[config])
    q = _queries(2000, "footprint", torch.float32, seed=1)
    out, grads = _outputs_and_gradients(m, q, MultiScale.eval)
    ref, ref_grads = _outputs_and_gradients(m, q, _reference_eval)
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-6 * float(ref.abs().max()))
    for (name, _), g, r in zip(m.named_parameters(), grads, ref_grads):
        torch.testing.assert_close(g, r, rtol=1e-3, atol=1e-4 * float(r.abs().max()), msg=name)
