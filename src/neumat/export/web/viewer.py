"""A self-contained HTML page that shows a material's GLSL export on a sphere or a plane (WebGL 2).

`write_viewer(model_or_export, path)` embeds the export's source (GLSL 3.30 turned into GLSL ES 3.00 by the
page's prelude) and its textures (base64 little-endian, at the export's precision: float16 uploaded as RGBA16F,
float32 as RGBA32F texture arrays) into `viewer.html`, the
template next to this file. The page renders `neumat.export.web.scene`'s scene: an orthographic camera, a
unit sphere or a square, a directional light; drag rotates the object, shift-drag moves the light; sliders set
the exposure and the uv tiling. Opening `path#test={json}` renders one view into a float framebuffer and
writes its linear values into the page (`neumat.export.web.headless.viewer_pixels` reads them).

The page calls `neumat_eval(wi, wo, uv, footprint)` with the pixel's uv footprint from dFdx / dFdy (box
filter, J J^T / 12, as neumat's renderer), or `neumat_eval(wi, wo)` for homogeneous exports. NeuPreSS
exports (object-space entry points) are refused.
"""
from __future__ import annotations

import base64
import html
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import InputError
from ..glsl import export_glsl
from ..glsl_common import GLSLExport
from ..registry import EXPORT_FORMATS, ExportFormat

TEMPLATE = Path(__file__).with_name("viewer.html")
SPATIAL = "vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)"
HOMOGENEOUS = "vec3 neumat_eval(vec3 wi, vec3 wo)"


def _adapter(shader: GLSLExport) -> str:
    """GLSL `nm_viewer_eval(wi, wo, uv, footprint)` calling the export's BRDF entry point."""
    entry = shader.entry_points()
    if SPATIAL in entry:
        call = "neumat_eval(wi, wo, uv, footprint)"
    elif HOMOGENEOUS in entry:
        call = "neumat_eval(wi, wo)"
    else:
        raise InputError(f"write_viewer: the export has no BRDF entry point ({SPATIAL!r} or {HOMOGENEOUS!r}); "
                         f"it defines {entry}")
    return f"\nvec3 nm_viewer_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint) {{ return {call}; }}\n"


def viewer_html(shader: GLSLExport, title: str) -> str:
    """The viewer page (a str) of a GLSL export."""
    textures = {}
    for name, data in shader.textures.items():
        layers, height, width, channels = data.shape
        if channels != 4:
            raise InputError(f"write_viewer: texture {name} has {channels} channels, expected RGBA (4)")
        half = data.dtype == np.float16
        textures[name] = {"width": width, "height": height, "layers": layers,
                          "format": "RGBA16F" if half else "RGBA32F",
                          "data": base64.b64encode(data.astype("<f2" if half else "<f4").tobytes()).decode("ascii")}
    source = shader.source + _adapter(shader)
    if "</script" in source.lower():
        raise InputError("write_viewer: the shader source contains '</script'")
    page = TEMPLATE.read_text()
    return (page.replace("__TITLE__", html.escape(title)).replace("__SHADER__", source)
            .replace("__DATA__", json.dumps({"textures": textures})))


def write_viewer(model_or_export, path: str | Path, title: str | None = None) -> Path:
    """Write the viewer page of a model (exported with `export_glsl`) or of a `GLSLExport` to `path` (an .html
    file; parent folders created). Returns the path."""
    shader = model_or_export if isinstance(model_or_export, GLSLExport) else export_glsl(model_or_export)
    if title is None:
        title = getattr(model_or_export, "name", None) or "neumat material"
    path = Path(path)
    if path.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"write_viewer: expected an .html path, got {str(path)!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(viewer_html(shader, title))
    return path


@dataclass(frozen=True)
class WebExport:
    """A viewer page to be written: the GLSL export it shows and its title."""

    shader: GLSLExport
    title: str

    def write(self, folder: str | Path) -> Path:
        """Write `folder`/viewer.html; returns its path."""
        return write_viewer(self.shader, Path(folder) / "viewer.html", self.title)

    def summary(self, path: Path) -> str:
        """What `write` wrote (`neumat export` prints it)."""
        return f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB): open it in a browser with WebGL 2"


def web_export(model, precision: str = "fp16") -> WebExport:
    """The viewer page of `model` (its GLSL export at `precision`); InputError for a model without a BRDF entry
    point, before anything is written."""
    shader = export_glsl(model, precision)
    _adapter(shader)
    return WebExport(shader, getattr(model, "name", None) or "neumat material")


EXPORT_FORMATS.register("web")(ExportFormat("self-contained WebGL 2 viewer page (viewer.html)", web_export))
