"""Why a NeuBRDF fit of an RGL file scores a low image SSIM: per-channel SSIM, where the SSIM is lost, the
linear radiance there, and the scores against the reference rendered raw (negative measured values kept) and
clamped (the comparison protocol since 77f2e7f). Renders are cached in $WORK (default /tmp/rgl_negative).

    python -m benchmarks.studies.neubrdf.rgl_negative.diagnose SRC.bsdf MODEL.nmat [MODEL.nmat ...]
"""
from __future__ import annotations

import os
import pickle
import sys
from pathlib import Path

import numpy as np
import torch
from skimage.metrics import structural_similarity

from neumat.catalog.modelfile import load_model
from neumat.catalog.open_material import open_material
from neumat.color.tonemap import to_ldr
from neumat.core.material import NonNegative
from neumat.metrics.image import image_metrics
from neumat.render.comparison import REFERENCE_FACTOR, comparison_images

SPP, RES = 512, 128
WORK = Path(os.environ.get("WORK", "/tmp/rgl_negative"))


def cached(name: str, make):
    path = WORK / f"{name}.pkl"
    if not path.exists():
        WORK.mkdir(parents=True, exist_ok=True)
        pickle.dump(make(), open(path, "wb"))
    return pickle.load(open(path, "rb"))


def render(material, spp: int, seed: int) -> np.ndarray:
    return np.asarray(comparison_images({"m": material}, spp, RES, seed)["m"])


def ldr(img) -> np.ndarray:
    return np.asarray(to_ldr(np.asarray(img), tonemap="clip"), dtype=np.float64)


def main(src: str, models: list[str]) -> None:
    torch.set_num_threads(1)
    ref = open_material(src)
    stem = Path(src).stem
    refs = {kind: (cached(f"{stem}_{kind}_ref", lambda: render(m, REFERENCE_FACTOR * SPP, 1)),
                   cached(f"{stem}_{kind}_floor", lambda: render(m, SPP, 0)))
            for kind, m in (("raw", ref), ("clamped", NonNegative(ref)))}
    h = RES
    yy, xx = np.mgrid[:h, :h]
    radius = np.hypot(yy - h / 2 + 0.5, xx - h / 2 + 0.5) / (h / 2)
    for kind, (r, floor) in refs.items():
        m = image_metrics(r, floor)
        print(f"floor ({kind} reference): SSIM {m['ssim']:.5f} MAE {m['mae']:.5f} FLIP {m['flip']:.5f}")
    for path in models:
        img = cached(f"{stem}_{Path(path).stem}", lambda: render(load_model(path), SPP, 0))
        for kind, (r, _) in refs.items():
            m = image_metrics(r, img)
            per = [structural_similarity(ldr(r)[..., c], ldr(img)[..., c], data_range=1.0) for c in range(3)]
            print(f"{Path(path).name} vs {kind}: SSIM {m['ssim']:.5f} (R / G / B {per[0]:.4f} / {per[1]:.4f} / "
                  f"{per[2]:.4f}) MAE {m['mae']:.5f} FLIP {m['flip']:.5f}")
        r = refs["raw"][0]
        _, smap = structural_similarity(ldr(r), ldr(img), data_range=1.0, channel_axis=2, full=True)
        loss = 1 - smap.mean(-1)
        blob = loss > 0.08
        if blob.any():
            print(f"  SSIM lost on the sphere: {loss[radius <= 1].sum() / loss.sum():.3f} of it; "
                  f"{int(blob.sum())} pixels lose > 0.08 (rows {yy[blob].min()}-{yy[blob].max()}, cols "
                  f"{xx[blob].min()}-{xx[blob].max()}); linear radiance there: raw reference "
                  f"{np.round(r[blob].mean(0), 6)}, clamped {np.round(refs['clamped'][0][blob].mean(0), 6)}, "
                  f"model {np.round(img[blob].mean(0), 6)}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
