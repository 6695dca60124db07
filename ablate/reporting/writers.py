"""The report's HTML form: its style sheet, and one self-contained report.html (figures and videos inlined).
The PDF is typeset from the Markdown instead (``typeset.py``): no browser is needed."""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222;
       line-height: 1.45; }
table { border-collapse: collapse; font-size: 0.85em; margin: 1em 0; }
caption { caption-side: top; text-align: left; font-size: 0.9em; color: #333; padding: 0.3em 0; }
th, td { border: 1px solid #ccc; padding: 4px 8px; text-align: left; vertical-align: top; }
img { max-width: 100%; }
figure { margin: 1.5em 0; break-inside: avoid; }
figcaption { font-size: 0.9em; color: #333; margin-top: 0.3em; }
.videos { display: flex; flex-wrap: wrap; gap: 12px; }
figure.video { margin: 0; width: 260px; font-size: 0.8em; }
figure.video video { width: 260px; }
blockquote { background: #fff4e0; border-left: 4px solid #f0a000; margin: 1em 0; padding: 0.5em 1em; }
@media print {
  body { max-width: none; margin: 0; font-size: 10pt; }
  video { display: none; }
  figure.video { width: 45%; }
  table { font-size: 8pt; }
  h2 { break-after: avoid; }
  tr { break-inside: avoid; }
}
"""


def _inline(html_text: str, folder: Path) -> str:
    """Replace relative ``src`` references with data URIs, so report.html is one self-contained file."""
    mime = {".png": "image/png", ".svg": "image/svg+xml", ".mp4": "video/mp4"}

    def replace(match: re.Match) -> str:
        path = folder / html.unescape(match.group(2))
        if not path.is_file():
            return match.group(0)
        data = base64.b64encode(path.read_bytes()).decode()
        return f'{match.group(1)}="data:{mime.get(path.suffix, "application/octet-stream")};base64,{data}"'

    return re.sub(r'(src)="((?:figures|videos)/[^"]+)"', replace, html_text)
