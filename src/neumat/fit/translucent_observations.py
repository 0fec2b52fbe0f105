"""Training data for translucent-object models: path-traced observations of S_hat under directional light.

As in NeuPreSS (Sec. 4.2): every image has its own random light direction and a camera orbiting the
object; only rays that hit the object are kept. An image here is an orthographic view of the object's
bounding sphere from a direction uniform on the sphere, with jittered pixel positions.
"""
from __future__ import annotations

import json
import time
import zipfile
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch

from ..core.checks import check_int
from ..core.config import config_to_dict
from ..core.errors import DataFormatError, InputError
from ..core.frames import frame_from_normal
from ..io.atomic import atomic_write
from ..reflectance.translucent import TranslucentConfig, TranslucentObject
from ..warp.sphere import sample_uniform_sphere


@dataclass
class Observations:
    """N observations, all (N, 3) float32 object space: surface point x, outward unit normal n, unit view
    direction wo (towards the camera), unit light direction wi (towards the light) and the observed S_hat
    (RGB, 1/sr; a Monte Carlo estimate, so a value may be slightly negative: `TranslucentObject.trace` subtracts
    two traces and does not clamp, which would bias it). Anything else raises InputError.

    `bbox`: the object's bounding box (lo (3,), hi (3,)) that `load` reads from the file's recorded source, or None;
    kept by indexing and `to` (the object does not change), used by `neumat.fit.translucent_fit.set_bounds_from`.
    `object_config`: the object's description (`TranslucentConfig` fields) that `load` reads from the same source, or
    None; kept alike, so that an online fit can trace the object again (`neumat.fit.translucent_online`)."""

    x: torch.Tensor
    n: torch.Tensor
    wo: torch.Tensor
    wi: torch.Tensor
    value: torch.Tensor

    def __post_init__(self) -> None:
        self.bbox: tuple[torch.Tensor, torch.Tensor] | None = None
        self.object_config: dict | None = None
        n = self.x.shape[0]
        for f in fields(self):
            t = getattr(self, f.name)
            if not isinstance(t, torch.Tensor) or t.shape != (n, 3):
                raise InputError(f"Observations.{f.name}: expected a tensor of shape ({n}, 3), "
                                 f"got {getattr(t, 'shape', type(t))}")
            if not bool(torch.isfinite(t).all()):
                raise InputError(f"Observations.{f.name} has non-finite values")
        for name in ("n", "wo", "wi"):
            err = (getattr(self, name).double().norm(dim=-1) - 1).abs()
            if n and float(err.max()) > 1e-3:
                raise InputError(f"Observations.{name}: expected unit vectors, {int((err > 1e-3).sum())} of {n} are "
                                 f"not (max |norm - 1| = {float(err.max()):.3g})")

    def __len__(self) -> int:
        return self.x.shape[0]

    def __getitem__(self, index) -> "Observations":
        return self._with_bbox(Observations(**{f.name: getattr(self, f.name)[index] for f in fields(self)}))

    def to(self, device: str | torch.device) -> "Observations":
        """The same observations on `device` (self when they are there already)."""
        if self.x.device == torch.device(device):
            return self
        return self._with_bbox(Observations(**{f.name: getattr(self, f.name).to(device) for f in fields(self)}))

    def _with_bbox(self, other: "Observations") -> "Observations":
        other.bbox, other.object_config = self.bbox, self.object_config
        return other

    def split(self, fraction: float, seed: int = 0) -> tuple["Observations", "Observations"]:
        """(rest, held-out) with a random `fraction` of the observations held out."""
        if not 0 < fraction < 1:
            raise InputError(f"split fraction: expected a number in (0, 1), got {fraction!r}")
        perm = torch.randperm(len(self), generator=torch.Generator().manual_seed(seed))
        k = max(1, int(round(fraction * len(self))))
        return self[perm[k:]], self[perm[:k]]

    def save(self, path: str | Path, source: dict | None = None) -> None:
        """Write an .npz file with the five arrays and, if given, `source` (a JSON-serialisable dict: what
        was traced, e.g. the object's config) for `load_source`."""
        extra = {} if source is None else {"source": np.array(json.dumps(source))}
        np.savez_compressed(path, **{f.name: getattr(self, f.name).numpy() for f in fields(self)}, **extra)

    @classmethod
    def load(cls, path: str | Path) -> "Observations":
        """Read what `save` wrote, with `bbox` from its recorded source; a missing, empty or truncated file, missing
        arrays or values that `Observations` refuses raise errors naming the file."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"observations file {path} does not exist")
        try:
            with np.load(path) as data:
                arrays = {f.name: torch.from_numpy(np.asarray(data[f.name], dtype=np.float32)) for f in fields(cls)}
        except (KeyError, ValueError, OSError, EOFError, zipfile.BadZipFile) as e:
            raise DataFormatError(f"{path}: not a neumat observations file (.npz of x, n, wo, wi, value; "
                                  f"empty or truncated?): {e}") from None
        try:
            obs = cls(**arrays)
        except InputError as e:
            raise DataFormatError(f"{path}: {e}") from None
        _check_mean_value(obs.value, path)
        source = cls.load_source(path) or {}
        obs.object_config = source.get("object")
        box = source.get("bbox")
        if box is not None:
            obs.bbox = tuple(torch.tensor(b, dtype=torch.float32) for b in box)
        return obs

    @staticmethod
    def load_source(path: str | Path) -> dict | None:
        """The `source` dict saved with the observations in `path` (None if none was saved), holding only the
        fields `neumat translucent trace` writes, each of its type (DataFormatError naming the file otherwise)."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"observations file {path} does not exist")
        try:
            with np.load(path) as data:
                if "source" not in data.files:
                    return None
                source = json.loads(str(data["source"]))
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as e:
            raise DataFormatError(f"{path}: not a neumat observations file ({e})") from None
        _check_source(source, f"{path}: source")
        return source


#: the fields of an observations file's `source` (`neumat translucent trace`) but "object" (a TranslucentConfig)
#: and "bbox" (the box [[lo], [hi]]), and their kinds (`neumat.io.tagged_file.FIELD_KINDS`)
SOURCE_FIELDS = {"spp": "a positive integer", "seed": "a non-negative integer", "noise": "a JSON object",
                 "trace_cpu_seconds": "a finite number"}


def _check_source(source, where: str) -> None:
    from ..core.config import config_from_dict
    from ..io.tagged_file import header_field
    from ..reflectance.translucent import TranslucentConfig

    if not isinstance(source, dict):
        raise DataFormatError(f"{where}: expected a JSON object (what `neumat translucent trace` writes), got "
                              f"{source!r}"[:300])
    known = {"object", "bbox", *SOURCE_FIELDS}
    if set(source) - known:
        raise DataFormatError(f"{where}: unknown field(s) {sorted(set(source) - known)} (known: {sorted(known)})")
    for key, kind in (*SOURCE_FIELDS.items(), ("object", "a JSON object")):
        header_field(source, key, kind, where, default=None)
    if "object" in source:
        try:
            config_from_dict(TranslucentConfig, source["object"])
        except InputError as e:
            raise DataFormatError(f"{where} field 'object': {e}") from None
    if "bbox" in source:
        box = np.asarray(source["bbox"], dtype=object)
        ok = box.shape == (2, 3) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in box.flat)
        if not ok or not (np.isfinite(box.astype(float)).all() and (box[0] < box[1]).all()):
            raise DataFormatError(f"{where} field 'bbox': expected [[lo x, y, z], [hi x, y, z]] with finite lo < hi, "
                                  f"got {source['bbox']!r}"[:300])


def _check_mean_value(value: torch.Tensor, path: Path) -> None:
    """Single values may be negative (each is a difference of two Monte Carlo traces, `TranslucentObject.trace`),
    but S_hat is >= 0, so a channel mean more than 4 standard errors below 0 is not such data: DataFormatError."""
    if value.shape[0] < 2:
        return
    v = value.double()
    mean, se = v.mean(0), v.std(0) / v.shape[0] ** 0.5
    bad = [c for c in range(3) if float(mean[c]) < -4 * float(se[c])]
    if bad:
        c = bad[0]
        raise DataFormatError(f"{path}: the mean observed value of channel {'RGB'[c]} is {float(mean[c]):.4g}, "
                              f"{float(-mean[c] / se[c]):.3g} standard errors below 0; single values may be negative "
                              "(each is a difference of two Monte Carlo traces), but S_hat is >= 0 on average")


def orbit_rays(obj: TranslucentObject, view: torch.Tensor, resolution: int,
               generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Origins and directions (R^2, 3) float64 of a jittered orthographic view of the bounding sphere from
    the unit direction `view` (3,) (the camera looks along -view)."""
    centre = torch.from_numpy((obj.bbox_min + obj.bbox_max) / 2)
    radius = obj.diagonal / 2
    t, b = frame_from_normal(view[None].double())
    u = (torch.arange(resolution, dtype=torch.float64)[:, None] + torch.rand(resolution, resolution, 2,
                                                                              generator=generator,
                                                                              dtype=torch.float64)[..., 0])
    v = (torch.arange(resolution, dtype=torch.float64)[None, :] + torch.rand(resolution, resolution,
                                                                              generator=generator,
                                                                              dtype=torch.float64))
    s = (2 * u / resolution - 1).reshape(-1, 1) * radius
    r = (2 * v / resolution - 1).reshape(-1, 1) * radius
    o = centre + 2 * radius * view.double() + s * t + r * b
    d = (-view.double()).expand_as(o).contiguous()
    return o, d


def collect_observations(obj: TranslucentObject, images: int, resolution: int = 32, spp: int | None = None,
                         seed: int = 0, progress: bool = False, checkpoint: str | Path | None = None,
                         resume: bool = False, checkpoint_every_s: float = 120.0) -> Observations:
    """Observations from `images` orthographic views (resolution^2 jittered rays each), each with its own
    light direction uniform on the sphere and camera direction uniform on the sphere; `spp` paths per ray
    (default: the object's).

    checkpoint: a file written every `checkpoint_every_s` seconds of tracing with the views done so far and the
    random state (a trace of the paper's size takes an hour or more); with `resume` an existing one is continued,
    and the result is the one an uninterrupted trace gives. The file is removed when the trace ends. What the
    trace cost is in `obj.trace_cpu_seconds` (a resumed trace's earlier sittings included)."""
    for name, v in (("images", images), ("resolution", resolution)):
        check_int(v, f"collect_observations {name}")
    if resume and checkpoint is None:
        raise InputError("collect_observations: resume needs a checkpoint path")
    gen = torch.Generator().manual_seed(int(seed))
    dirs = sample_uniform_sphere(torch.rand(2 * images, 2, generator=gen, dtype=torch.float64))
    parts: dict[str, list[torch.Tensor]] = {f.name: [] for f in fields(Observations)}
    key = {"images": images, "resolution": resolution, "spp": obj.spp if spp is None else spp, "seed": int(seed),
           "object_seed": obj.seed, "object": config_to_dict(obj.config)}
    start = 0
    if resume and Path(checkpoint).is_file():
        start = _resume_trace(checkpoint, key, gen, obj, parts)
    views = range(start, images)
    if progress:
        from rich.progress import track
        views = track(views, description="path tracing views" + (f" (resumed at {start})" if start else ""))
    saved = time.monotonic()
    for k in views:
        light, view = dirs[2 * k], dirs[2 * k + 1]
        o, d = orbit_rays(obj, view, resolution, gen)
        hit, x, n = obj.first_hits(o, d)
        if bool(hit.any()):
            value = obj.trace(o[hit], d[hit], light, spp=spp)
            m = int(hit.sum())
            for name, t in (("x", x), ("n", n), ("wo", -d[hit]), ("wi", light.expand(m, 3)), ("value", value)):
                parts[name].append(t.float())
        if checkpoint is not None and k + 1 < images and time.monotonic() - saved >= checkpoint_every_s:
            _save_trace(checkpoint, key, k + 1, gen, obj, parts)
            saved = time.monotonic()
    if not parts["x"]:
        raise InputError("collect_observations: no view hit the object")
    obs = Observations(**{name: torch.cat(ts) for name, ts in parts.items()})
    if checkpoint is not None:
        Path(checkpoint).unlink(missing_ok=True)
    return obs


def _save_trace(path, key: dict, views: int, gen: torch.Generator, obj: TranslucentObject,
                parts: dict[str, list[torch.Tensor]]) -> None:
    """A trace's checkpoint: what it traced (key), the views done, the random state and the observations so far
    (each field's parts joined, so that the next save appends to one tensor)."""
    for name, ts in parts.items():
        if len(ts) > 1:
            parts[name] = [torch.cat(ts)]
    blob = {"trace": key, "views": views, "generator": gen.get_state(), "calls": obj.trace_calls,
            "cpu_seconds": obj.trace_cpu_seconds,
            "parts": {name: ts[0] if ts else torch.zeros(0, 3) for name, ts in parts.items()}}
    atomic_write(path, lambda tmp: torch.save(blob, tmp))


def _resume_trace(path, key: dict, gen: torch.Generator, obj: TranslucentObject,
                  parts: dict[str, list[torch.Tensor]]) -> int:
    """Load a trace's checkpoint into gen, obj and parts; the view to continue at. Errors name the file when it is
    unreadable or was written for another trace."""
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
        saved, views = blob["trace"], int(blob["views"])
    except Exception as e:  # noqa: BLE001 - any unreadable file is reported the same way
        raise DataFormatError(f"trace checkpoint {str(path)!r}: cannot be read ({e})") from None
    if saved != key:
        diff = sorted(k for k in key if saved.get(k) != key[k])
        raise InputError(f"trace checkpoint {str(path)!r} was written for another trace (different "
                         f"{', '.join(diff)}); trace with the same options or start a new checkpoint")
    gen.set_state(blob["generator"])
    obj.trace_calls = int(blob["calls"])
    obj.trace_cpu_seconds = float(blob.get("cpu_seconds", float("nan")))  # checkpoints before it: unknown
    for name, t in blob["parts"].items():
        if len(t):
            parts[name].append(t)
    return views


def traced_object(path: str | Path, seed: int = 0) -> TranslucentObject:
    """The TranslucentObject an observations file of `neumat translucent trace` describes (one path per query: for
    rendering and scoring against it); InputError when the file describes none."""
    from ..core.config import config_from_dict

    source = Observations.load_source(path)
    if source is None or "object" not in source:
        raise InputError(f"{path}: no object description (write it with `neumat translucent trace`)")
    return TranslucentObject(config_from_dict(TranslucentConfig, source["object"]), spp=1, seed=seed)
