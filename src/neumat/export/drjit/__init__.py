"""The Dr.Jit runtime export target ("drjit"): learned models translated once into Dr.Jit arrays and evaluated in
Mitsuba 3's own kernels (symbolic / megakernel mode, LLVM or CUDA), without torch.

- `neumat.export.drjit.runtime` (imports no torch): the export's files, `load_runtime`, and the shared pieces
  (HEALPix `vec2pix`, NeuBRDF's direction inputs, the `drjit.nn` MLP).
- `neumat.export.drjit.format`: the "drjit" entry of the export registry; a method declares its translator as
  `neumat.fit.method.Method.drjit` (model -> (manifest, arrays)), e.g. `neumat.methods.neubrdf.drjit`.

- `neumat.export.drjit.latent` (no torch): the latent-texture family's programs (registered on import, here):
  "latent-mlp" there, "neumip" and "ggx-mipmap" in `neumat.export.drjit.neumip`, "neural-appearance" (the decoder
  and its learned sampler) in `neumat.export.drjit.neural_appearance`, "sparse-btf" in
  `neumat.export.drjit.sparse_btf`.
- `neumat.export.drjit.neubrdf` (no torch): "healpix-grid-mlp", the NeuBRDF forms "healpix-mlp" does not cover
  (inverse-distance corner weights, a neural texture, shared-NeuBRDF's several materials).

Details: docs/mitsuba.md, section "Native Dr.Jit runtime".
"""
from . import latent  # noqa: F401  (registers the "latent-mlp" program in runtime.PROGRAMS)
from . import neumip  # noqa: F401  (registers "neumip" and "ggx-mipmap")
from . import neubrdf  # noqa: F401  (registers "healpix-grid-mlp")
from . import neural_appearance  # noqa: F401  (registers "neural-appearance")
from . import sparse_btf  # noqa: F401  (registers "sparse-btf")
