"""`dvc plots show` works offline with vendor/vega/dvc_plots_template.html."""

import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
VENDOR = REPO / "vendor" / "vega"
TEMPLATE = VENDOR / "dvc_plots_template.html"


def load_make_template():
    spec = importlib.util.spec_from_file_location("make_template", VENDOR / "make_template.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bundles_and_licences_are_vendored():
    for name in ("vega", "vega-lite", "vega-embed"):
        assert (VENDOR / f"{name}.min.js").stat().st_size > 10_000
        assert "Copyright" in (VENDOR / f"LICENSE-{name}").read_text()


def test_vendored_versions_are_the_ones_dvc_renders_with():
    from dvc_render.vega import VegaRenderer

    cdn = dict(re.findall(r"npm/([a-z-]+)@([\d.]+)", VegaRenderer.SCRIPTS))
    bundles = {name: version for name, version, _ in load_make_template().BUNDLES}
    assert bundles == cdn
    # the files are those versions
    assert 'var e="5.20.2"' in (VENDOR / "vega.min.js").read_text()[:400]
    assert 'var n="5.2.0"' in (VENDOR / "vega-lite.min.js").read_text()[:400]


def test_template_is_current_and_has_dvcs_plot_slot_but_no_cdn_scripts():
    text = TEMPLATE.read_text(encoding="utf-8")
    assert text == load_make_template().build_template()  # rebuilt from the vendored files
    assert "{plot_divs}" in text
    assert "{scripts}" not in text  # DVC would insert its CDN <script src=...> tags there
    assert not re.search(r"<script[^>]*\bsrc=", text)
    assert text.count("<script") == 3


def dvc_plots_html(tmp_path: Path) -> str:
    """Run `dvc plots show` with the template in a throwaway repository."""
    for tool in ("git",):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} not installed")
    dvc = [sys.executable, "-m", "dvc"]
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    subprocess.run(dvc + ["init", "-q"], cwd=tmp_path, check=True)
    (tmp_path / "pr.csv").write_text("recall,precision\n0.1,1.0\n0.5,0.8\n0.9,0.4\n")
    subprocess.run(dvc + ["plots", "show", "pr.csv", "-x", "recall", "-y", "precision",
                          "--html-template", str(TEMPLATE), "-o", "out"],
                   cwd=tmp_path, check=True, capture_output=True)
    return (tmp_path / "out" / "index.html").read_text(encoding="utf-8")


def test_dvc_plots_show_writes_a_page_without_remote_scripts(tmp_path):
    html = dvc_plots_html(tmp_path)
    assert "vegaEmbed('#" in html
    assert not re.search(r"<script[^>]*\bsrc=", html)
    assert "cdn.jsdelivr.net" not in html


NODE_RENDER = r"""
const fs = require('fs'); const vm = require('vm');
const html = fs.readFileSync(process.argv[2], 'utf8');
const scripts = [...html.matchAll(/<script type="text\/javascript">([\s\S]*?)<\/script>/g)];
for (const m of scripts) vm.runInThisContext(m[1]);
const specs = [...html.matchAll(/var spec = ([\s\S]*?);\n\s*vegaEmbed/g)]
  .map(m => JSON.parse(m[1]));
(async () => {
  for (const spec of specs) {
    const view = new vega.View(vega.parse(vegaLite.compile(spec).spec), {renderer: 'none'});
    const svg = await view.toSVG();
    console.log(typeof vegaEmbed, svg.includes('<path') ? 'drawn' : 'empty');
  }
})().catch(e => { console.error(e); process.exit(1); });
"""


def test_the_page_renders_with_the_inlined_bundles(tmp_path):
    """Evaluate the page's inline scripts as a browser would and render DVC's spec to SVG."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node not installed")
    page = tmp_path / "page.html"
    page.write_text(dvc_plots_html(tmp_path))
    # a script file, not `node -e`: there `module`/`exports` are globals and the bundles would
    # take their CommonJS path instead of the browser one
    script = tmp_path / "render.js"
    script.write_text(NODE_RENDER)
    out = subprocess.run([node, str(script), str(page)], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["function", "drawn"]
