"""`neumat mitsuba-render`: render a Mitsuba 3 scene file whose BSDFs may be neumat materials and whose integrator
may be `neumat_translucent` (a NeuPreSS object in the scene)."""
from __future__ import annotations

from pathlib import Path

import typer

from ..core.errors import InputError
from .common import IMAGE_OUT, SEED_RANGE, output_option, parse_overrides, run_command


def register(app: typer.Typer) -> None:
    app.command("mitsuba-render")(mitsuba_render)


def mitsuba_render(scene_arg: Path = typer.Argument(..., metavar="SCENE", help="Mitsuba 3 scene file (.xml)"),
                   define: list[str] = typer.Option(None, "-D", "--define",
                                                    help="scene parameter NAME=VALUE (the XML's $NAME), repeatable"),
                   spp: int = typer.Option(None, min=1, help="samples per pixel (default: the scene's sampler)"),
                   seed: int = typer.Option(0, **SEED_RANGE),
                   variant: str = typer.Option("llvm_ad_rgb", help="Mitsuba RGB variant: llvm_ad_rgb (the CPU, "
                                               "needs LLVM >= 16) or cuda_ad_rgb (an NVIDIA GPU, no LLVM needed; "
                                               "native models run their fp16 Dr.Jit runtime there)"),
                   out: Path = typer.Option(..., "-o", "--out", callback=output_option(*IMAGE_OUT),
                                            help="output image (.png, .exr, .hdr)")) -> None:
    """Render SCENE with Mitsuba's integrator; `<bsdf type="neumat"><string name="material" value="..."/></bsdf>`
    puts any neumat material (model file, measured file, texture-set folder, analytic spec) in it, and
    `<integrator type="neumat_translucent">` a translucent NeuPreSS object (docs/mitsuba.md)."""
    from ..integrations import mitsuba as plugin
    from ..integrations import mitsuba_translucent
    from ..io.images import write_image

    def go():
        from ..io.shared_data import resolve_data_path
        scene = resolve_data_path(scene_arg)  # docs/examples/scene.xml also from an installed wheel
        if not scene.is_file():
            raise InputError(f"scene file {str(scene)!r} does not exist")
        params = parse_overrides(define, "-D", text=True)  # Mitsuba substitutes the text as written
        mi = mitsuba_translucent.register(variant)  # the neumat BSDF and the translucent integrator
        try:
            loaded = mi.load_file(str(scene), **params)
        except (RuntimeError, UnicodeDecodeError) as e:  # the parser: the message names the file, line, problem
            # a message quoting a file's bytes (a PLY header of random bytes) fails to decode: decode it leniently
            why = str(e.object.decode("utf-8", "replace") if isinstance(e, UnicodeDecodeError)
                      else plugin.unwrap_error(e) or e)
            why = "".join(c if c.isprintable() else " " for c in why)
            raise InputError(f"Mitsuba could not load {str(scene)!r} or a file it names: {' '.join(why.split())}"
                             ) from None
        image = plugin.render(loaded, spp=spp, seed=seed)
        write_image(out, image[..., :3])
        print(f"wrote {out}")
    run_command(go)

