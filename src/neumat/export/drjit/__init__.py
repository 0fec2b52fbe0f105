"""The Dr.Jit runtime export target ("drjit"): learned models translated once into Dr.Jit arrays and evaluated in
Mitsuba 3's own kernels (symbolic / megakernel mode, LLVM or CUDA), without torch.

- `neumat.export.drjit.runtime` (imports no torch): the export's files, `load_runtime`, the shared pieces, and the
  programs "healpix-mlp", "direction-mlp", "ggx".
- `neumat.export.drjit.format`: the "drjit" entry of the export registry; a method declares its translator as
  `neumat.fit.method.Method.drjit` (model -> (manifest, arrays)), e.g. `neumat.methods.neubrdf.drjit`.
- Program modules (no torch; each registers its programs on import, here): `.latent` ("latent-mlp"), `.neumip`
  ("neumip", "ggx-mipmap"), `.neural_appearance`, `.sparse_btf`, `.neubrdf` ("healpix-grid-mlp"), `.neupress`
  (NeuPreSS's S_hat and light sampler, for the scene integrator `neumat.integrations.mitsuba_translucent`).

Details: docs/formats/drjit.md; docs/mitsuba.md, section "Native Dr.Jit runtime".
"""
from . import latent  # noqa: F401  (registers the "latent-mlp" program in runtime.PROGRAMS)
from . import neumip  # noqa: F401  (registers "neumip" and "ggx-mipmap")
from . import neubrdf  # noqa: F401  (registers "healpix-grid-mlp")
from . import neural_appearance  # noqa: F401  (registers "neural-appearance")
from . import sparse_btf  # noqa: F401  (registers "sparse-btf")
from . import neupress  # noqa: F401  (registers "neupress": NeuPreSS, for the translucent integrator)
