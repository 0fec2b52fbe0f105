"""`neumat check`: run the shipped physics and sampling tests on any material."""
from __future__ import annotations

import math

import typer

from .common import SEED_RANGE, print_json, print_table, run_command


def register(app: typer.Typer) -> None:
    app.command()(check)


def check(material: str = typer.Argument(..., help="material file (.binary, .bsdf, .nmat) or analytic spec"),
          angles: str = typer.Option("0,30,60,80", help="incident zenith angles in degrees, comma separated"),
          samples: int = typer.Option(1 << 18, min=1000, help="samples per chi-square test and furnace estimate"),
          seed: int = typer.Option(0, **SEED_RANGE),
          uv: str = typer.Option("0.5,0.5", help="texture coordinates u,v at which a spatially varying material "
                                                 "(texture set, layered .json, BTF, textured model) is tested"),
          json: bool = typer.Option(False, "--json", help="print one JSON object instead of a table")) -> None:
    """Chi-square test of sample() against pdf() over the whole sphere (when the material samples; a BRDF
    sampler may send glossy samples below the horizon with their pdf), white-furnace albedo and
    reciprocity, at each incident angle. Exits with status 1 when a test fails."""
    import torch

    from ..core.errors import InputError
    from ..core.query import Query
    from ..catalog.open_material import open_material
    from ..testing.chi2 import chi2_material
    from ..testing.furnace import white_furnace
    from ..testing.reciprocity import reciprocity_check

    def go() -> bool:
        try:
            degrees = [float(a) for a in angles.split(",") if a.strip()]
        except ValueError:
            raise InputError(f"--angles: expected comma-separated degrees, got {angles!r}") from None
        if not degrees or any(not 0 <= a < 90 for a in degrees):
            raise InputError(f"--angles: expected zenith angles in [0, 90) degrees, got {angles!r}")
        try:
            texel = torch.tensor([float(x) for x in uv.split(",")])
        except ValueError:
            texel = torch.zeros(0)
        if texel.shape != (2,) or not bool(((texel >= 0) & (texel <= 1)).all()):
            raise InputError(f"--uv: expected two texture coordinates in [0, 1] such as 0.5,0.5, got {uv!r}")
        m = open_material(material)
        at = {"uv": texel} if m.spatially_varying else {}
        rows, ok = [], True
        for a in degrees:
            t = math.radians(a)
            wi = torch.tensor([math.sin(t), 0.0, math.cos(t)])
            furnace = white_furnace(m, wi, n_samples=samples, seed=seed, **at)
            row = {"theta_i_deg": a, "albedo_rgb": [round(float(v), 4) for v in furnace.albedo[0]],
                   "albedo_stderr": round(float(furnace.stderr[0].max()), 5)}
            if m.can_sample:
                template = Query(wi[None], uv=texel[None]) if m.spatially_varying else None
                # over the whole sphere (the default), with quadrature that resolves grazing lobes
                res = chi2_material(m, wi, n_samples=samples, seed=seed, n_tests=len(degrees), template=template,
                                    quad=16)
                row.update(chi2_passed=res.passed, chi2_p_value=res.p_value)
                ok &= res.passed
            rows.append(row)
        recip = reciprocity_check(m, seed=seed)
        ok &= recip.passed
        summary = {"material": m.describe(), **({"uv": uv} if at else {}), "can_sample": m.can_sample,
                   "reciprocity_max_rel": recip.max_rel, "reciprocity_passed": recip.passed, "passed": ok}
        if json:
            print_json({**summary, "angles": rows})
        else:
            print_table(f"check {material}", rows)
            print_table("summary", [summary])
        return ok

    if not run_command(go):
        raise typer.Exit(1)
