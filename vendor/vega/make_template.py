"""Build ``dvc_plots_template.html``: DVC's plots page with Vega inlined (works offline).

DVC's own page loads Vega, Vega-Lite and vega-embed from cdn.jsdelivr.net through its
``{scripts}`` placeholder, so ``dvc plots show`` renders blank pages without network. This
template has no ``{scripts}`` placeholder (DVC then inserts no CDN tags) and inlines the three
vendored bundles instead, so the written HTML is self-contained wherever it is opened.

Run from anywhere: ``python vendor/vega/make_template.py``. Enable it with (path relative to
``.dvc/``): ``dvc config plots.html_template ../vendor/vega/dvc_plots_template.html``.
"""

from __future__ import annotations

import re
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: Same versions as DVC 3.67's CDN tags (dvc_render/vega.py), so its Vega-Lite specs match.
BUNDLES = (
    ("vega", "5.20.2", "vega.min.js"),
    ("vega-lite", "5.2.0", "vega-lite.min.js"),
    ("vega-embed", "6.18.2", "vega-embed.min.js"),
)
SOURCE_MAP = re.compile(r"\n?//# sourceMappingURL=\S+\s*$")

PAGE = """<!DOCTYPE html>
<html>
<head>
    {refresh_tag}
    <meta charset="utf-8">
    <title>DVC Plot</title>
{inline_scripts}
    <style>
        table {{
            border-spacing: 15px;
        }}
    </style>
</head>
<body>
    {plot_divs}
</body>
</html>
"""


def inline_script(name: str, version: str, filename: str) -> str:
    """One ``<script>`` element holding a vendored bundle (source-map comment removed)."""
    code = SOURCE_MAP.sub("", (HERE / filename).read_text(encoding="utf-8"))
    if "</script" in code.lower():
        raise ValueError(f"{filename}: contains '</script', cannot be inlined")
    opening = f'    <script type="text/javascript">/* {name} {version} (see LICENSE-{name}) */'
    return f"{opening}\n{code}\n    </script>"


def build_template() -> str:
    """The template text: DVC's page with the three bundles inlined."""
    scripts = "\n".join(inline_script(*bundle) for bundle in BUNDLES)
    # str.format would trip on braces in the JavaScript: substitute the one slot by hand.
    page = PAGE.replace("{{", "{").replace("}}", "}")
    return page.replace("{inline_scripts}", scripts)


if __name__ == "__main__":
    out = HERE / "dvc_plots_template.html"
    out.write_text(build_template(), encoding="utf-8")
    print(f"wrote {out} ({out.stat().st_size} bytes)")
