"""The report as a list of sections, written as ``report.md`` and a self-contained ``index.html``.

One content model, two renderings: a section holds text (with `code` spans), tables
(pandas DataFrames), figures (PNG/SVG beside the report), animations (MP4 or GIF beside
the report) and notes on figures that could not be drawn. The HTML embeds every PNG as
base64 and has its style inline; it plays the animations from ``figures/`` (``<video>``
with controls for MP4), so it opens offline with its folder. ``report.md`` links them.
Numbers in tables are shown to three significant digits.
"""

from __future__ import annotations

import base64
import html
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd


@dataclass
class Text:
    text: str


@dataclass
class Table:
    frame: pd.DataFrame
    caption: str = ""


@dataclass
class FigureRef:
    name: str  # file stem under figures/
    title: str
    caption: str


@dataclass
class VideoRef:
    name: str  # file stem under figures/
    title: str
    caption: str
    file: str  # file name under figures/: .mp4 (H.264) or .gif


@dataclass
class Note:
    title: str
    text: str
    error: str = ""

    @property
    def message(self) -> str:
        if self.error:
            return f"Not drawn: drawing failed ({self.error})."
        return f"Not drawn: needs {self.text}."


@dataclass
class Section:
    title: str
    blocks: list = field(default_factory=list)


def _cell(v) -> str:
    if isinstance(v, float):
        if math.isnan(v):
            return "–"
        if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e5):
            return f"{v:.2e}"
        return f"{v:.3g}"  # three significant digits
    if isinstance(v, bool):
        return "yes" if v else ""
    return str(v)


def markdown_table(df: pd.DataFrame) -> str:
    head = "| " + " | ".join(str(c) for c in df.columns) + " |"
    rule = "|" + "|".join("---" for _ in df.columns) + "|"
    rows = [
        "| " + " | ".join(_cell(v).replace("|", "\\|").replace("\n", " ") for v in row) + " |"
        for row in df.itertuples(index=False)
    ]
    return "\n".join([head, rule, *rows])


def to_markdown(title: str, sections: list[Section]) -> str:
    out = [f"# {title}", ""]
    for sec in sections:
        out += [f"## {sec.title}", ""]
        for b in sec.blocks:
            if isinstance(b, Text):
                out += [b.text, ""]
            elif isinstance(b, Table):
                if b.caption:
                    out += [f"*{b.caption}*", ""]
                out += [markdown_table(b.frame) if len(b.frame) else "(none)", ""]
            elif isinstance(b, FigureRef):
                out += [
                    f"### {b.title}",
                    "",
                    f"![{b.title}](figures/{b.name}.png)",
                    "",
                    f"{b.caption} ([SVG](figures/{b.name}.svg))",
                    "",
                ]
            elif isinstance(b, VideoRef):
                kind = Path(b.file).suffix.lstrip(".").upper()
                out += [
                    f"### {b.title}",
                    "",
                    f"[▶ {b.title} ({kind})](figures/{b.file})",
                    "",
                    b.caption,
                    "",
                ]
            elif isinstance(b, Note):
                out += [f"### {b.title}", "", f"*{b.message}*", ""]
    return "\n".join(out).rstrip() + "\n"


def _inline(text: str) -> str:
    """Escape, then the two bits of markdown the report uses: `code` and **bold**."""
    t = html.escape(text)
    t = re.sub(r"`([^`]+)`", r"<code>\1</code>", t)
    return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", t)


STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em;
       color: #222; line-height: 1.45; }
h1 { border-bottom: 2px solid #ccc; } h2 { margin-top: 2em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.5em 0 1em;
        display: block; max-width: 100%; overflow-x: auto; }
td, th { border: 1px solid #ccc; padding: 2px 6px; text-align: right; }
th { background: #f2f2f2; } figure { margin: 1em 0; } img, video { max-width: 100%; }
figcaption { font-size: 0.9em; color: #444; } code { background: #f4f4f4; padding: 0 3px; }
.note { color: #8a5a00; }
"""


def _video_html(v: VideoRef) -> str:
    src = f"figures/{html.escape(v.file)}"
    if v.file.endswith(".gif"):
        media = f'<img alt="{html.escape(v.title)}" src="{src}">'
    else:
        media = (
            f'<video controls loop muted playsinline preload="metadata" src="{src}">'
            f'<a href="{src}">{html.escape(v.file)}</a></video>'
        )
    return (
        f"<figure><h3>{_inline(v.title)}</h3>{media}"
        f'<figcaption>{_inline(v.caption)} (<a href="{src}">{html.escape(v.file)}</a>)'
        "</figcaption></figure>"
    )


def to_html(title: str, sections: list[Section], figures_dir: Path) -> str:
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title><style>{STYLE}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
    ]
    for sec in sections:
        out.append(f"<h2>{_inline(sec.title)}</h2>")
        for b in sec.blocks:
            if isinstance(b, Text):
                out.append(f"<p>{_inline(b.text)}</p>")
            elif isinstance(b, Table):
                if b.caption:
                    out.append(f"<p><i>{_inline(b.caption)}</i></p>")
                frame = b.frame.map(_cell) if len(b.frame) else b.frame
                out.append(
                    frame.to_html(index=False, border=0) if len(b.frame) else "<p>(none)</p>"
                )
            elif isinstance(b, FigureRef):
                png = (figures_dir / f"{b.name}.png").read_bytes()
                data = base64.b64encode(png).decode("ascii")
                out.append(
                    f"<figure><h3>{_inline(b.title)}</h3>"
                    f'<img alt="{html.escape(b.title)}" src="data:image/png;base64,{data}">'
                    f"<figcaption>{_inline(b.caption)}</figcaption></figure>"
                )
            elif isinstance(b, VideoRef):
                out.append(_video_html(b))
            elif isinstance(b, Note):
                out.append(f"<h3>{_inline(b.title)}</h3><p class='note'>{_inline(b.message)}</p>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"
