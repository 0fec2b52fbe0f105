"""One self-contained HTML report: headings, text, base64-embedded PNG images and tables."""
from __future__ import annotations

import base64
import html
import io
import numbers
from pathlib import Path

import numpy as np
from PIL import Image

from ..core.errors import InputError

_CSS = """
body { font-family: system-ui, sans-serif; max-width: 1200px; margin: 2em auto; padding: 0 1em; color: #222; }
h1 { border-bottom: 2px solid #444; }
h2 { margin-top: 2em; border-bottom: 1px solid #bbb; }
figure { display: inline-block; margin: 0.5em 1em 0.5em 0; vertical-align: top; }
figure img { max-width: 100%; image-rendering: pixelated; }
figcaption { font-size: 0.9em; color: #555; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; display: block; max-width: 100%;
        overflow-x: auto; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; overflow-wrap: anywhere; }
th { background: #eee; }
td:first-child, th:first-child { text-align: left; }
"""


def write_report(path: str | Path, title: str, sections: list[dict]) -> Path:
    """Write one HTML file with every image embedded; returns the path.

    sections: dicts with "heading" (str), optional "text" (str; blank lines separate paragraphs),
    optional "images" (list of (caption, uint8 (H, W, 3) image)) and optional "table" (list of dicts,
    one per row; columns are the union of the keys in first-seen order; numbers shown with 4 significant digits).
    """
    parts = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
             f"<title>{html.escape(title)}</title>", f"<style>{_CSS}</style>", "</head>", "<body>",
             f"<h1>{html.escape(title)}</h1>"]
    for k, section in enumerate(sections):
        parts.extend(_section(section, k))
    parts.extend(["</body>", "</html>", ""])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


def _section(section: dict, index: int) -> list[str]:
    if not isinstance(section, dict) or "heading" not in section:
        raise InputError(f"write_report: section {index} must be a dict with a 'heading', got {section!r:.80}")
    unknown = set(section) - {"heading", "text", "images", "table"}
    if unknown:
        raise InputError(f"write_report: section {index} has unknown key(s) {sorted(unknown)} "
                         "(known: heading, text, images, table)")
    out = [f"<h2>{html.escape(str(section['heading']))}</h2>"]
    for paragraph in str(section.get("text") or "").split("\n\n"):
        if paragraph.strip():
            out.append(f"<p>{html.escape(paragraph.strip())}</p>")
    for caption, image in section.get("images") or []:
        out.append(f'<figure><img src="data:image/png;base64,{_png_base64(image, caption)}" '
                   f'alt="{html.escape(str(caption))}"><figcaption>{html.escape(str(caption))}</figcaption></figure>')
    if section.get("table"):
        out.append(_table(section["table"]))
    return out


def _png_base64(image, caption) -> str:
    arr = np.asarray(image)
    if arr.dtype != np.uint8 or arr.ndim != 3 or arr.shape[2] != 3:
        raise InputError(f"write_report: image {caption!r} must be uint8 (H, W, 3), got {arr.dtype} {arr.shape}")
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _table(rows: list[dict]) -> str:
    columns = list(dict.fromkeys(key for row in rows for key in row))
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in columns)
    body = ["<tr>" + "".join(f"<td>{html.escape(_cell(row.get(c, '')))}</td>" for c in columns) + "</tr>"
            for row in rows]
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _cell(value) -> str:
    if isinstance(value, numbers.Real) and not isinstance(value, (bool, numbers.Integral)):
        return f"{value:.4g}"
    return str(value)
