"""Renderer throughput: a sphere of analytic GGX and Lambert under an importance-sampled environment map.

    python benchmarks/studies/render/render.py                          # 512 x 512, 64 spp, CPU (2 threads) and CUDA if present
    python benchmarks/studies/render/render.py --resolution 128 --spp 16 --threads 1 --strategies mis,light,material

Prints seconds and megasamples (camera samples) per second per configuration, with the machine load
(1-minute load average) measured before each CPU run, since shared machines distort CPU timings. One
warm-up render (small) precedes the timed ones on each device.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import torch
from rich.console import Console
from rich.table import Table

from neumat.reflectance.analytic import GGX, Lambert
from neumat.render.render import render

SHARED_ENV = Path(__file__).resolve().parents[2] / "shared" / "data" / "envmap" / "forest_slope_1k.hdr"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    ap.add_argument("--light", default=f"env:{SHARED_ENV}" if SHARED_ENV.is_file() else "env:sky")
    ap.add_argument("--strategies", default="mis")
    ap.add_argument("--devices", default="cpu,cuda", help="comma-separated; cuda is skipped when unavailable")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    devices = [d for d in args.devices.split(",") if d != "cuda" or torch.cuda.is_available()]
    materials = {"ggx": GGX(0.3), "lambert": Lambert(0.5)}
    rows = []
    for device in devices:
        render(GGX(0.3), light=args.light, spp=4, resolution=32, device=device)  # warm-up
        for name, material in materials.items():
            for strategy in args.strategies.split(","):
                load = os.getloadavg()[0] if device == "cpu" else float("nan")
                _sync(device)
                t0 = time.perf_counter()
                img = render(material, light=args.light, spp=args.spp, resolution=args.resolution,
                             strategy=strategy, device=device)
                _sync(device)
                seconds = time.perf_counter() - t0
                samples = args.resolution ** 2 * args.spp
                rows.append({"material": name, "strategy": strategy, "device": _device_name(device),
                             "seconds": seconds, "Msamples/s": samples / seconds / 1e6,
                             "mean": float(img.mean()), "load avg": load})
    t = Table(title=f"render: sphere {args.resolution}x{args.resolution}, {args.spp} spp, {Path(args.light).name}; "
                    f"ggx = GGX(roughness 0.3, aluminium), lambert = Lambert(0.5); cpu xN = N torch threads "
                    f"on {os.cpu_count()} cores")
    for k in rows[0]:
        t.add_column(k)
    for r in rows:
        t.add_row(*(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r.values()))
    Console().print(t)


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def _device_name(device: str) -> str:
    if device.startswith("cuda"):
        return torch.cuda.get_device_name(torch.device(device))
    return f"cpu x{torch.get_num_threads()}"


if __name__ == "__main__":
    main()
