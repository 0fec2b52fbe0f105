"""BTF commands: `neumat fit-dictionary` (SparseBTF ensemble training) and `neumat data btf-generate`."""
from __future__ import annotations

from pathlib import Path

import typer

from .common import SEED_RANGE, device_option, output_option, print_table, run_command


def parse_tau(text: str) -> tuple[int, int, int]:
    from ..core.errors import InputError
    parts = [p for p in text.replace("/", ",").split(",") if p]
    try:
        vals = [int(p) for p in parts]
    except ValueError:
        raise InputError(f"--tau {text!r}: expected one integer or Y,U,V integers such as 256,32,32") from None
    if len(vals) == 1:
        vals *= 3
    if len(vals) != 3:
        raise InputError(f"--tau {text!r}: expected one integer or three (Y,U,V)")
    return tuple(vals)


def register(app: typer.Typer) -> None:
    """Add `fit-dictionary` to the main app."""

    @app.command("fit-dictionary")
    def fit_dictionary(
            btfs: list[Path] = typer.Argument(..., help=".nbtf files of the training set (one direction set)"),
            out: Path = typer.Option(..., "-o", "--out", callback=output_option(".nmat"),
                                     help="output dictionary file (.nmat)"),
            dictionaries: int = typer.Option(None, "--dictionaries", "-k", min=1,
                                             help="K dictionaries per ensemble [default: SparseBTF Config]"),
            tau: str = typer.Option(None, "--tau", help="training sparsity tau_l, Y,U,V or one value "
                                                        "[default: SparseBTF Config.tau_train]"),
            patch: int = typer.Option(None, "--patch", min=1, help="spatial patch size of a data point "
                                                            "[default: SparseBTF Config]"),
            fraction: float = typer.Option(None, "--fraction", help="random fraction of data points used "
                                                                    "[default: sparse-btf recipe]"),
            iterations: int = typer.Option(None, "--iterations", min=1, help="maximum training iterations "
                                                                      "[default: sparse-btf recipe steps - 1]"),
            seed: int = typer.Option(None, "--seed", help="[default: sparse-btf recipe]", **SEED_RANGE),
            device: str = typer.Option(None, "--device", callback=device_option),
            quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output")) -> None:
        """Train the SparseBTF dictionary ensemble once on a few BTFs. Warns when the data points are too few for K
        (fewer than the paper's 360 per dictionary: neumat.methods.sparse_btf.dictionary_train.training_size_warning);
        the BTFs' texels must split into --patch x --patch patches (btf-generate's default --size does)."""
        from neumat.methods.sparse_btf.dictionary_train import train_dictionary
        from ..reflectance.btf import read_btf

        def go():
            data = [read_btf(p, device=device) for p in btfs]
            d = train_dictionary(data, dictionaries, None if tau is None else parse_tau(tau), patch,
                                 sample_fraction=fraction, max_iters=iterations, seed=seed, progress=not quiet)
            d.save(out)
            rows = [{"channel": ch, "iterations": d.info["iterations"][ch], "seconds": d.info["seconds"][ch],
                     "objective": d.info["objective"][ch][-1]} for ch in "YUV"]
            print_table(f"dictionary {out} ({d.info['points']} data points)", rows)
        run_command(go)


def register_data(data_app: typer.Typer) -> None:
    """Add `btf-generate` to the `neumat data` sub-app. Its default --size is a multiple of SparseBTF's
    Config.patch, so that `neumat fit-dictionary` takes its output with its own defaults."""
    from neumat.methods.sparse_btf.model import Config
    patch = Config.patch

    @data_app.command("btf-generate")
    def btf_generate(
            textures: Path = typer.Argument(..., help="PBR texture-set folder (color, roughness, displacement, ...), "
                                            "or procedural:<class>[~<variant>] (bumps, weave, bricks, dents, ridges)"),
            out: Path = typer.Option(..., "-o", "--out", callback=output_option(".nbtf"), help="output .nbtf file"),
            size: int = typer.Option(6 * patch, "--size", min=1,
                                     help=f"BTF resolution (size x size texels; a multiple of SparseBTF's patch "
                                          f"{patch} for fit-dictionary's defaults)"),
            crop: int = typer.Option(0, "--crop", min=0, help="crop this many source texels first (0: the whole set)"),
            directions: str = typer.Option("hemi151", "--directions",
                                           help="direction set: hemi151, ubo81, rings:<n>x<deg> or a count"),
            spp: int = typer.Option(4, "--spp", min=1, help="sub-pixel rays per texel (square number)"),
            relief: float = typer.Option(0.0, "--relief", help="texels of displacement per height unit (0: from the "
                                                                "set; 4 for a procedural material)"),
            noise: float = typer.Option(0.0, "--noise", min=0.0,
                                        help="relative std of measurement-like sensor noise (0: none)"),
            interreflection: int = typer.Option(0, "--interreflection", min=0,
                                                help="one bounce of inter-reflection with this many hemisphere "
                                                     "directions per ray hit (a square number; 0: direct light only)"),
            fibres: float = typer.Option(0.0, "--fibres", min=0.0, max=1.0,
                                         help="anisotropy in [0, 1] of the GGX lobe along fibres (0: isotropic)"),
            fibre_direction: str = typer.Option("grain", "--fibre-direction",
                                                help="fibre field: grain (along the height map's ridges), "
                                                     "weave:<p> (p x p-texel plain weave), angle:<deg>"),
            device: str = typer.Option(None, "--device", callback=device_option),
            quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output")) -> None:
        """Generate a BTF from a PBR texture set (or a procedural material) by ray marching its displaced height
        field."""
        from ..io.btf import write_btf
        from ..io.texture_set import load_texture_set
        from ..reflectance.btf import direction_set
        from ..reflectance.btf_generate import generate_btf, texture_tile
        from ..reflectance.procedural_texture import RELIEF, parse_material, procedural_texture_set

        def go():
            if str(textures).startswith("procedural:"):
                kind, variant = parse_material(str(textures).removeprefix("procedural:"))
                tile, tile_relief = procedural_texture_set(kind, size, seed=1, variant=variant), RELIEF
            else:
                tile, tile_relief = texture_tile(load_texture_set(textures), size, crop or None)
            d = direction_set(int(directions) if directions.isdigit() else directions)
            btf = generate_btf(tile, d, d, relief=relief or tile_relief, spp=spp, device=device, progress=not quiet,
                               label=tile.name, noise=noise, interreflection=interreflection, fibres=fibres,
                               fibre_direction=fibre_direction)
            write_btf(out, btf, extra={"source": str(textures), "crop": crop, "relief": relief or tile_relief})
            print(f"wrote {out}: {size}x{size} texels, {d.shape[0]}x{d.shape[0]} directions "
                  f"({out.stat().st_size} bytes)")
            if size % patch:
                print(f"note: {size} texels do not split into SparseBTF's {patch} x {patch} patches (Config.patch): "
                      f"`neumat fit-dictionary` will need --patch dividing {size}, or generate with --size "
                      f"{max(patch, size // patch * patch)} or {(size // patch + 1) * patch}")
        run_command(go)
