"""Dr.Jit runtime program "neural-appearance" (imports no torch): Real-Time Neural Appearance Models' BRDF decoder
(the "neumip" program's: latent pyramid, 2 learned shading frames, SiLU MLP; `neumat.export.drjit.neumip`) with
its learned importance sampler (`neumat.methods.neural_appearance.proxy_sampler`): a ReLU MLP from (wi, z_s) to the
two-lobe proxy's raw parameters (`neumat.warp.microfacet_proxy.proxy_from_raw`; the "isotropic" ablation's 2
outputs padded as `isotropic_raw`), sampled in closed form with the defensive cosine share (`DEFENSIVE`).

z_s is the filtered latent at uv (trilinear over the footprint; the sampler's features, `sampling_features`), read
once per query and shared by the lobes and the decoder; the lobes are computed once and shared by the sampled
direction and its density (`sample_eval`, `eval_pdf`: what the Mitsuba BSDF calls). With "roulette" level
selection (or the offset module) the decoder reads its own two levels (the shifted uv), as `NeuMIP.eval` does.
"""
from __future__ import annotations

import math

from ...core.errors import DataFormatError
from .neumip import NeuMip, _uv_footprint
from .runtime import PROGRAMS, Mlp, mlp_layers

#: the defensive cosine share (`neumat.methods.neural_appearance.proxy_sampler.DEFENSIVE`)
DEFENSIVE = 0.05
#: `neumat.warp.microfacet_proxy.MIN_ALPHA` / `MAX_RHO`
MIN_ALPHA, MAX_RHO = 1e-3, 0.99


def _soft_tanh(x):
    import drjit as dr
    c = dr.clip(x, -2.0, 2.0)
    return c * (1 - dr.abs(c) / 4)


def _soft_sinh(x):
    import drjit as dr
    return x * (1 + dr.abs(x) / 2)


def _cosine_hemisphere(u0, u1) -> list:
    """`neumat.warp.hemisphere.sample_cosine_hemisphere`: the concentric disk lifted up."""
    import drjit as dr

    a, c = 2 * u0 - 1, 2 * u1 - 1
    first = dr.abs(a) > dr.abs(c)
    r = dr.select(first, a, c)
    phi = dr.select(first, (math.pi / 4) * c / dr.select(a == 0, 1.0, a),
                    math.pi / 2 - (math.pi / 4) * a / dr.select(c == 0, 1.0, c))
    px, py = r * dr.cos(phi), r * dr.sin(phi)
    return [px, py, dr.sqrt(dr.maximum(1 - (px * px + py * py), 0.0))]


def _dot(a: list, b: list):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


class Lobes:
    """The two-lobe proxy of one query per lane (`ProxyLobes`), with the pieces sample and pdf share: w_d, the
    diffuse normal n_d, alpha (ax, ay), rho, sqrt(1 - rho^2), mu_s."""

    def __init__(self, raw: list) -> None:
        import drjit as dr

        m = dr.maximum(raw[0], raw[3])  # softmax over (w_d, w_s) as torch computes it
        e0, e3 = dr.exp(raw[0] - m), dr.exp(raw[3] - m)
        self.w_d = e0 / (e0 + e3)
        mu_d = [_soft_sinh(raw[1]), _soft_sinh(raw[2])]
        n = [-mu_d[0], -mu_d[1], 1.0]
        inv = 1 / dr.sqrt(n[0] * n[0] + n[1] * n[1] + 1.0)
        self.n_d = [n[0] * inv, n[1] * inv, inv]
        self.ax, self.ay = (MIN_ALPHA + (1 - MIN_ALPHA) * (_soft_tanh(raw[k]) + 1) / 2 for k in (4, 5))
        self.rho = MAX_RHO * _soft_tanh(raw[6])
        self.s = dr.sqrt(1 - self.rho * self.rho)
        self.mu_s = [_soft_sinh(raw[7]), _soft_sinh(raw[8])]

    def sample_proxy(self, wi: list, u0, u1) -> list:
        """`neumat.warp.microfacet_proxy.sample_proxy`: u0 picks the lobe and is rescaled."""
        import drjit as dr

        diffuse = u0 < self.w_d
        u0 = dr.select(diffuse, u0 / dr.maximum(self.w_d, 1e-12), (u0 - self.w_d) / dr.maximum(1 - self.w_d, 1e-12))
        local = _cosine_hemisphere(dr.clip(u0, 0.0, 1 - 1e-7), u1)
        x, y, z = self.n_d  # frame_from_normal (Duff et al.)
        sign = dr.select(z >= 0, 1.0, -1.0)
        a = -1 / (sign + z)
        bb = x * y * a
        t = [1 + sign * x * x * a, sign * bb, -sign * x]
        bt = [bb, sign + y * y * a, -y]
        wo_d = [local[0] * t[k] + local[1] * bt[k] + local[2] * self.n_d[k] for k in range(3)]
        h = [self.ax * local[0] - self.mu_s[0] * local[2],
             self.ay * self.rho * local[0] + self.ay * self.s * local[1] - self.mu_s[1] * local[2], local[2]]
        inv = 1 / dr.sqrt(_dot(h, h))
        h = [v * inv for v in h]
        d = 2 * _dot(wi, h)
        return [dr.select(diffuse, wo_d[k], d * h[k] - wi[k]) for k in range(3)]

    def proxy_pdf(self, wi: list, wo: list):
        """`neumat.warp.microfacet_proxy.proxy_pdf`."""
        import drjit as dr

        p_d = dr.maximum(_dot(wo, self.n_d), 0.0) / math.pi
        h = [wi[k] + wo[k] for k in range(3)]
        flip = h[2] < 0
        h = [dr.select(flip, -v, v) for v in h]
        length = dr.sqrt(_dot(h, h))
        ok = (length > 1e-12) & (h[2] > 0)
        inv = 1 / dr.select(ok, length, 1.0)
        h = [v * inv for v in h]
        px, py = h[0] + self.mu_s[0] * h[2], h[1] + self.mu_s[1] * h[2]
        x = px / self.ax
        y = (py - self.ay * self.rho * x) / (self.ay * self.s)
        det_inv = 1 / (self.ax * self.ay * self.s)
        r = dr.sqrt(x * x + y * y + h[2] * h[2])
        p_h = (h[2] / r) / math.pi * det_inv / (r * r * r)
        cos_oh = dr.abs(_dot(wo, h))
        p_s = dr.select(ok & (cos_oh > 0), p_h / (4 * dr.maximum(cos_oh, 1e-12)), 0.0)
        return self.w_d * p_d + (1 - self.w_d) * p_s

    def sample(self, wi: list, u0, u1) -> list:
        """`sample_defensive`: a cosine-weighted direction with probability DEFENSIVE, the proxy's otherwise."""
        import drjit as dr

        cosine = u0 < DEFENSIVE
        u0 = dr.clip(dr.select(cosine, u0 / DEFENSIVE, (u0 - DEFENSIVE) / (1 - DEFENSIVE)), 0.0, 1 - 1e-7)
        c = _cosine_hemisphere(u0, u1)
        p = self.sample_proxy(wi, u0, u1)
        wo = [dr.select(cosine, c[k], p[k]) for k in range(3)]
        inv = 1 / dr.sqrt(_dot(wo, wo))
        return [v * inv for v in wo]

    def pdf(self, wi: list, wo: list):
        """`defensive_pdf`."""
        import drjit as dr
        return (1 - DEFENSIVE) * self.proxy_pdf(wi, wo) + DEFENSIVE * dr.maximum(wo[2], 0.0) / math.pi


class NeuralAppearance(NeuMip):
    """Program "neural-appearance" (module docstring): the "neumip" manifest and arrays, and sampler_lobes
    ("anisotropic" / "isotropic"), sampler_activation; arrays sampler_layer{i}_weight / _bias (input: wi, then
    z_s). `sample`, `pdf` and the shared `sample_eval` / `eval_pdf` take uv and footprint as `eval` does."""

    can_sample = True

    def __init__(self, manifest: dict, arrays: dict, backend, compute: str, mlp_form: str | None = None) -> None:
        super().__init__(manifest, arrays, backend, compute, mlp_form)
        self.lobe_family = manifest.get("sampler_lobes", "anisotropic")
        outputs = {"anisotropic": 9, "isotropic": 2}.get(self.lobe_family)
        layers = mlp_layers(arrays, "sampler_layer")
        if outputs is None or not layers or layers[0][0].shape[1] != 3 + self.pyramid.channels \
                or layers[-1][0].shape[0] != outputs:
            raise DataFormatError(f"drjit export ({self.describe()}): the sampler does not match the manifest")
        self.sampler = Mlp(backend, layers, manifest.get("sampler_activation", "relu"), compute, mlp_form)
        self.shares_latent = self.offset is None and not self.roulette

    # ---------------------------------------------------------------------------------------- pieces
    def latent(self, uv, footprint, active) -> list:
        """z_s at uv (the sampler's features; the decoder's latent unless roulette or offset): C Floats."""
        u, v, fp = _uv_footprint(self.backend, uv, footprint)
        return self.pyramid.filter(u, v, fp, active)

    def lobes(self, wi: list, z: list) -> Lobes:
        raw = self.sampler([wi[0], wi[1], wi[2], *z])
        if self.lobe_family == "isotropic":  # isotropic_raw: [w_d, 0, 0, 0, alpha, alpha, 0, 0, 0]
            zero = self.backend.Float(0.0)
            raw = [raw[0], zero, zero, zero, raw[1], raw[1], zero, zero, zero]
        return Lobes(raw)

    def _value(self, z: list, wi: list, wo: list, ok, uv, footprint):
        """BRDF value (Array3f) at wi, wo: decoded from the shared latent z where it is the decoder's, else `eval`."""
        import drjit as dr

        if not self.shares_latent:
            return self.eval(self.backend.Array3f(*wi), self.backend.Array3f(*wo), ok, uv, footprint)
        ok = ok & (wi[2] > 0) & (wo[2] > 0)
        out = [dr.exp(x) for x in self._decode(z, list(wi), list(wo))]
        return dr.select(ok, self.backend.Array3f(*out), 0.0)

    # ---------------------------------------------------------------------------------------- API
    def sample(self, wi, u0, u1, active=True, uv=None, footprint=None):
        """(wo Array3f, pdf Float) of the learned sampler for wi (lanes with wi below the horizon: pdf 0)."""
        wo, pdf, _ = self.sample_eval(wi, u0, u1, active, uv, footprint, value=False)
        return wo, pdf

    def pdf(self, wi, wo, active=True, uv=None, footprint=None):
        import drjit as dr

        b = self.backend
        ok = b.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        wi, wo = [wi[0], wi[1], wi[2]], [wo[0], wo[1], wo[2]]
        lobes = self.lobes(wi, self.latent(uv, footprint, ok))
        return dr.select(ok, lobes.pdf(wi, wo), 0.0)

    def sample_eval(self, wi, u0, u1, active=True, uv=None, footprint=None, swap: bool = False, value=True):
        """(wo, pdf, f) with the latent read once and the lobes computed once: wo sampled for wi, its density, and
        the BRDF value f(wi, wo) (f(wo, wi) with swap: Mitsuba's importance transport), as `NeuralAppearance.sample`
        draws them; 0 where wi or wo is below the horizon."""
        import drjit as dr

        b = self.backend
        up = b.Bool(active) & (wi[2] > 0)
        wl = [dr.select(up, wi[0], 0.0), dr.select(up, wi[1], 0.0), dr.select(up, wi[2], 1.0)]
        z = self.latent(uv, footprint, up)
        lobes = self.lobes(wl, z)
        wo = lobes.sample(wl, u0, u1)
        ok = up & (wo[2] > 0)
        pdf = dr.select(ok, lobes.pdf(wl, wo), 0.0)
        f = None
        if value:
            a, c = (wo, wl) if swap else (wl, wo)
            f = self._value(z, a, c, ok, uv, footprint)
        return b.Array3f(*wo), pdf, f

    def eval_pdf(self, wi, wo, active=True, uv=None, footprint=None, swap: bool = False):
        """(f, pdf) at wi, wo with the latent read once: f(wi, wo) (f(wo, wi) with swap) and the sampler's density
        of wo given wi."""
        import drjit as dr

        b = self.backend
        ok = b.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        wi, wo = [wi[0], wi[1], wi[2]], [wo[0], wo[1], wo[2]]
        z = self.latent(uv, footprint, ok)
        pdf = dr.select(ok, self.lobes(wi, z).pdf(wi, wo), 0.0)
        a, c = (wo, wi) if swap else (wi, wo)
        return self._value(z, a, c, ok, uv, footprint), pdf


PROGRAMS["neural-appearance"] = NeuralAppearance
