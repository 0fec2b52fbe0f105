"""PBR texture sets (color, normal, roughness, metalness, height maps) read from a folder.

Two naming styles are recognised, by the last ``_``-separated token of each file name (case-insensitive):

- ambientCG: ``Wood092_1K-JPG_Color.jpg``, ``_NormalGL``, ``_NormalDX``, ``_Roughness``, ``_Displacement``,
  ``_Metalness``;
- cc0textures: ``Fabric02_col.jpg``, ``_nrm`` (OpenGL), ``_rgh``, ``_disp``, ``_met``.

Orientation: maps keep the image layout (row 0 is the top row of the file). Texel (row i, column j) has its
centre at uv = ((j + 0.5) / W, 1 - (i + 0.5) / H): u points right and v points up in the image, and the
tangent frame is x = +u, y = +v, z = out of the surface (the OpenGL normal-map convention). DirectX normal
maps have their y flipped on reading.

Height: a map value h in [0, 1] is a displacement of ``height_scale * h`` in units of the texture width
(texels are square), so normals derived from height do not change when the set is downscaled.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..color.tonemap import srgb_encode, srgb_to_linear
from ..core.errors import DataFormatError, InputError

#: file-name token (lowercase) -> map kind
MAP_TOKENS = {
    "color": "color", "col": "color", "basecolor": "color", "albedo": "color", "diffuse": "color",
    "normalgl": "normal_gl", "nrm": "normal_gl", "normal": "normal_gl", "normaldx": "normal_dx",
    "roughness": "roughness", "rgh": "roughness",
    "displacement": "height", "disp": "height", "height": "height",
    "metalness": "metalness", "met": "metalness", "metallic": "metalness",
}
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")

#: default displacement of a map value of 1, in texture widths: regressing the NormalGL slopes of the
#: shared ambientCG sets on their height gradients gives 0.0004 (Metal027) to 0.0075 (Plaster001)
DEFAULT_HEIGHT_SCALE = 0.002


@dataclass
class TextureSet:
    """The maps of one PBR material as float32 torch tensors, all of the same size H x W.

    color:     (H, W, 3) linear RGB base colour (sRGB-decoded).
    normal:    (H, W, 3) unit tangent-space normals (x = +u, y = +v, z up; OpenGL convention).
    roughness: (H, W) perceptual roughness in [0, 1] (alpha = roughness^2).
    metalness: (H, W) in [0, 1]; zeros when the set has no metalness map.
    height:    (H, W) displacement map value in [0, 1]; zeros when the set has no displacement map.
    name:      material name (the folder name).
    normal_from_height: True when `normal` was derived from `height` by finite differences.
    height_scale: displacement (texture widths) of a height value of 1.
    """

    color: torch.Tensor
    normal: torch.Tensor
    roughness: torch.Tensor
    metalness: torch.Tensor
    height: torch.Tensor
    name: str = "texture_set"
    normal_from_height: bool = False
    height_scale: float = DEFAULT_HEIGHT_SCALE

    def __post_init__(self) -> None:
        h, w = self.color.shape[:2]
        expected = {"color": (h, w, 3), "normal": (h, w, 3), "roughness": (h, w), "metalness": (h, w),
                    "height": (h, w)}
        for key, shape in expected.items():
            t = getattr(self, key)
            if not isinstance(t, torch.Tensor) or tuple(t.shape) != shape:
                got = tuple(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__
                raise InputError(f"TextureSet.{key}: expected shape {shape}, got {got}")

    @property
    def size(self) -> tuple[int, int]:
        """(H, W) in texels."""
        return tuple(self.color.shape[:2])

    def crop(self, row: int, col: int, height: int, width: int) -> "TextureSet":
        """The sub-rectangle of `height` x `width` texels starting at (row, col); normals are kept as
        computed on the full set."""
        h, w = self.size
        if not (0 <= row and 0 <= col and height >= 1 and width >= 1 and row + height <= h and col + width <= w):
            raise InputError(f"TextureSet.crop: rectangle rows {row}..{row + height}, cols {col}..{col + width} "
                             f"is not inside the {h} x {w} set")
        s = (slice(row, row + height), slice(col, col + width))
        return replace(self, color=self.color[s], normal=self.normal[s], roughness=self.roughness[s],
                       metalness=self.metalness[s], height=self.height[s])

    def to(self, device=None) -> "TextureSet":
        """The same set with every map on `device`."""
        return replace(self, **{k: getattr(self, k).to(device)
                                for k in ("color", "normal", "roughness", "metalness", "height")})


def find_maps(folder: Path) -> dict[str, Path]:
    """Map kind -> file of a texture-set folder (see MAP_TOKENS); duplicate kinds raise."""
    found: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        kind = MAP_TOKENS.get(path.stem.rsplit("_", 1)[-1].lower())
        if kind is None:
            continue
        if not path.is_file():  # a FIFO or device would block or never end
            raise DataFormatError(f"texture set {folder}: {path.name} is not a regular file")
        if kind in found:
            raise DataFormatError(f"texture set {folder}: two {kind} maps, {found[kind].name} and {path.name}")
        found[kind] = path
    return found


_DIRECT_MODES = ("L", "LA", "RGB", "RGBA", "I", "I;16", "I;16B", "I;16L", "F")


def _read(path: Path) -> np.ndarray:
    """Image as float32 (H, W, C) in [0, 1], no transfer function applied."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            if im.mode not in _DIRECT_MODES:  # palette, CMYK, YCbCr, LAB, 1-bit: decode to RGB(A)
                im = im.convert("RGBA" if im.mode in ("PA", "P") and "transparency" in im.info
                                or im.mode == "PA" else "RGB")
            mode = im.mode
            a = np.asarray(im)
    except (OSError, SyntaxError, Image.DecompressionBombError) as e:
        raise DataFormatError(f"{path}: cannot read image ({e})") from e
    if mode in ("I;16", "I;16B", "I;16L", "I"):
        a = a.astype(np.float32) / 65535.0
    elif a.dtype == np.uint8:
        a = a.astype(np.float32) / 255.0
    elif a.dtype == np.uint16:
        a = a.astype(np.float32) / 65535.0
    else:
        a = a.astype(np.float32)
    return a[..., None] if a.ndim == 2 else a


def _channels(a: np.ndarray, n: int, path: Path) -> np.ndarray:
    """The first n colour channels of image a (H, W, C); grey images are broadcast."""
    if a.shape[2] >= n:
        return a[..., :n]
    if a.shape[2] in (1, 2):
        return np.repeat(a[..., :1], n, axis=2)
    raise DataFormatError(f"{path}: expected {n} channel(s), got {a.shape[2]}")


def _resize(t: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Antialiased bilinear resize of a (H, W, C) map to `size` = (H', W')."""
    x = t.permute(2, 0, 1).unsqueeze(0)
    return F.interpolate(x, size=size, mode="bilinear", antialias=True, align_corners=False)[0].permute(1, 2, 0)


def normals_from_height(height: torch.Tensor, height_scale: float) -> torch.Tensor:
    """Unit tangent-space normals (H, W, 3) of the surface z = height_scale * height (texture widths).

    Central differences with wrap-around (the set tiles); n is proportional to (-dz/du, -dz/dv, 1) with
    u to the right and v up in the image (row index grows downwards).
    """
    h, w = height.shape
    z = height * height_scale
    dz_du = (torch.roll(z, -1, 1) - torch.roll(z, 1, 1)) * (w / 2.0)  # texel pitch 1/W in texture widths
    dz_drow = (torch.roll(z, -1, 0) - torch.roll(z, 1, 0)) * (w / 2.0)
    n = torch.stack([-dz_du, dz_drow, torch.ones_like(z)], -1)  # dz/dv = -dz/drow
    return n / n.norm(dim=-1, keepdim=True)


def load_texture_set(folder: str | Path, height_scale: float = DEFAULT_HEIGHT_SCALE,
                     max_size: int | None = None, crop: int | None = None,
                     crop_origin: tuple[int, int] | list[int] | None = None) -> TextureSet:
    """Read a PBR texture set folder (see the module docstring for names and conventions).

    Needs a color and a roughness map, and a normal map or a displacement map (normals are then derived
    from height). `max_size` downscales (antialiased) so that max(H, W) <= max_size before normals are
    derived. `crop` instead keeps crop x crop texels at full resolution (no resampling; normals
    from height are derived on the whole map first, so the crop's are those of the full set), from the top-left
    corner or from `crop_origin` = (row, col). Raises InputError for a bad folder or argument, DataFormatError for
    missing, unreadable or mismatched maps.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"texture set folder {str(folder)!r} does not exist or is not a folder")
    if not (isinstance(height_scale, (int, float)) and height_scale > 0):
        raise InputError(f"load_texture_set height_scale: expected a positive number, got {height_scale!r}")
    if max_size is not None and (isinstance(max_size, bool) or not isinstance(max_size, int) or max_size < 1):
        raise InputError(f"load_texture_set max_size: expected a positive integer or None, got {max_size!r}")
    if crop is not None and (isinstance(crop, bool) or not isinstance(crop, int) or crop < 1):
        raise InputError(f"load_texture_set crop: expected a positive integer or None, got {crop!r}")
    if crop_origin is not None and (crop is None or not isinstance(crop_origin, (tuple, list))
                                    or len(crop_origin) != 2
                                    or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0
                                               for v in crop_origin)):
        raise InputError(f"load_texture_set crop_origin: expected (row, col), two integers >= 0, with crop, got "
                         f"crop_origin={crop_origin!r}, crop={crop!r}")
    if crop is not None and max_size is not None:
        raise InputError(f"load_texture_set: give max_size or crop, not both (got max_size={max_size}, crop={crop})")
    files = find_maps(folder)
    missing = [k for k in ("color", "roughness") if k not in files]
    if not any(k in files for k in ("normal_gl", "normal_dx", "height")):
        missing.append("normal or displacement")
    if missing:
        raise DataFormatError(f"texture set {folder}: missing {', '.join(missing)} map(s) "
                              f"(found: {', '.join(p.name for p in files.values()) or 'no recognised maps'})")
    if "normal_gl" in files and "normal_dx" in files:
        raise DataFormatError(f"texture set {folder}: both an OpenGL and a DirectX normal map")

    raw = {k: _read(p) for k, p in files.items()}
    sizes = {files[k].name: a.shape[:2] for k, a in raw.items()}
    if len(set(sizes.values())) > 1:
        listing = ", ".join(f"{name} {s[1]}x{s[0]}" for name, s in sizes.items())
        raise DataFormatError(f"texture set {folder}: maps have different sizes ({listing}); expected one size")

    maps = {
        "color": torch.from_numpy(srgb_to_linear(_channels(raw["color"], 3, files["color"])).astype(np.float32)),
        "roughness": torch.from_numpy(_channels(raw["roughness"], 1, files["roughness"]).copy()),
    }
    for k in ("metalness", "height"):
        if k in raw:
            maps[k] = torch.from_numpy(_channels(raw[k], 1, files[k]).copy())
    normal_kind = "normal_gl" if "normal_gl" in raw else "normal_dx" if "normal_dx" in raw else None
    if normal_kind:
        n = torch.from_numpy(_channels(raw[normal_kind], 3, files[normal_kind]).copy()) * 2 - 1
        if normal_kind == "normal_dx":
            n[..., 1] = -n[..., 1]
        maps["normal"] = n

    h, w = raw["color"].shape[:2]
    if max_size is not None and max(h, w) > max_size:
        s = max_size / max(h, w)
        size = (max(1, round(h * s)), max(1, round(w * s)))
        maps = {k: _resize(v, size) for k, v in maps.items()}
        h, w = size
    if crop is not None and (crop > h or crop > w):
        raise InputError(f"load_texture_set crop: {crop} is larger than the {w}x{h} maps of {folder}")
    zeros = torch.zeros(h, w)
    height = maps["height"][..., 0] if "height" in maps else zeros
    if "normal" in maps:
        n = maps["normal"]
        n = torch.where(n[..., 2:] > 0, n, torch.cat([n[..., :2], torch.full_like(n[..., 2:], 1e-3)], -1))
        normal = n / n.norm(dim=-1, keepdim=True)
    else:
        normal = normals_from_height(height, float(height_scale))
    full = TextureSet(color=maps["color"].contiguous(), normal=normal.contiguous(),
                      roughness=maps["roughness"][..., 0].clamp(0, 1).contiguous(),
                      metalness=(maps["metalness"][..., 0].clamp(0, 1) if "metalness" in maps else zeros).contiguous(),
                      height=height.contiguous(), name=folder.name, normal_from_height=normal_kind is None,
                      height_scale=float(height_scale))
    return full if crop is None else full.crop(*(crop_origin or (0, 0)), crop, crop)


def write_texture_set(textures: TextureSet, folder: str | Path) -> Path:
    """Write `textures` as a texture-set folder that `load_texture_set` reads: <name>_Color.png (8-bit sRGB),
    <name>_NormalGL.png (8-bit, OpenGL convention), and 16-bit <name>_Roughness.png, <name>_Metalness.png,
    <name>_Displacement.png. The displacement's scale (textures.height_scale) is not stored: a reader derives
    nothing from it, since the normal map is written. Returns the folder (created)."""
    from PIL import Image

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"write_texture_set: {folder} is a file; expected a folder")
    folder.mkdir(parents=True, exist_ok=True)
    name = textures.name

    def unit8(a: torch.Tensor) -> np.ndarray:
        return np.round(a.detach().cpu().clamp(0, 1).numpy() * 255).astype(np.uint8)

    def unit16(a: torch.Tensor) -> np.ndarray:
        return np.round(a.detach().cpu().clamp(0, 1).numpy() * 65535).astype(np.uint16)

    Image.fromarray(unit8(srgb_encode(textures.color.float()))).save(folder / f"{name}_Color.png")
    Image.fromarray(unit8(textures.normal.float() * 0.5 + 0.5)).save(folder / f"{name}_NormalGL.png")
    for kind, values in (("Roughness", textures.roughness), ("Metalness", textures.metalness),
                         ("Displacement", textures.height)):
        Image.fromarray(unit16(values.float())).save(folder / f"{name}_{kind}.png")
    return folder
