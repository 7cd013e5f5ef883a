"""The viewer's 3D library, measured: three.js (what ``mbsim view`` embeds) against plotly.js
(the plotly Python package's offline bundle), on the vehicle over 6 s with 601 outputs.

    python benchmarks/view_libraries.py [--deck vehicle] [--outputs 601]

For each library one self-contained page of the same mechanism (the same triangles, the same
centroid and Euler-parameter arrays) is opened in headless Chromium (mbsim.view.browser,
software WebGL); a script run at the page's load event steps through every output and records,
in the DOM that --dump-dom prints:

- first frame: ms from navigation start to the end of the first drawn frame (three.js:
  renderer.render; plotly: Plotly.newPlot returned);
- per output: ms to move every body to the output and draw (three.js: setTime + render + a
  one-pixel readPixels, which waits for the GPU, over all outputs; plotly: Plotly.restyle of
  every body's x, y, z over the first --plotly-outputs outputs).

Prints the page sizes and the medians of --repeat browser runs.  Needs chromium and the plotly
package (pip install plotly) for the plotly half.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

THREE_PROBE = """<script>
window.addEventListener('load', () => {
  const v = window.mbsimView, c = v.state.c, gl = v.renderer.getContext();
  const px = new Uint8Array(4);
  const t0 = performance.now();
  for (let k = 0; k < c.nt; k++) {
    v.setTime(c.time[k]);
    v.renderer.render(v.scene, v.camera);
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
  }
  document.body.dataset.frameMs = ((performance.now() - t0) / c.nt).toFixed(3);
});
</script></body>"""

PLOTLY_PAGE = """<!DOCTYPE html><html><head><meta charset="utf-8"><title>plotly probe</title>
<script>{plotly}</script></head><body><div id="p" style="width:780px;height:650px"></div>
<script id="d" type="application/json">{data}</script>
<script>
const D = JSON.parse(document.getElementById('d').textContent);
function pose(b, k) {{  // vertices of body b at output k: r + A(p) v
  const [e0, e1, e2, e3] = b.p.slice(4 * k, 4 * k + 4), r = b.r.slice(3 * k, 3 * k + 3);
  const A = [[2*(e0*e0+e1*e1)-1, 2*(e1*e2-e0*e3), 2*(e1*e3+e0*e2)],
             [2*(e1*e2+e0*e3), 2*(e0*e0+e2*e2)-1, 2*(e2*e3-e0*e1)],
             [2*(e1*e3-e0*e2), 2*(e2*e3+e0*e1), 2*(e0*e0+e3*e3)-1]];
  const n = b.v.length / 3, x = new Array(n), y = new Array(n), z = new Array(n);
  for (let i = 0; i < n; i++) {{
    const a = b.v[3*i], c = b.v[3*i+1], d = b.v[3*i+2];
    x[i] = r[0] + A[0][0]*a + A[0][1]*c + A[0][2]*d;
    y[i] = r[1] + A[1][0]*a + A[1][1]*c + A[1][2]*d;
    z[i] = r[2] + A[2][0]*a + A[2][1]*c + A[2][2]*d;
  }}
  return [x, y, z];
}}
const traces = D.bodies.map((b) => {{
  const [x, y, z] = pose(b, 0), f = b.f;
  const i = [], j = [], k = [];
  for (let t = 0; t < f.length; t += 3) {{ i.push(f[t]); j.push(f[t+1]); k.push(f[t+2]); }}
  return {{type: 'mesh3d', x, y, z, i, j, k, color: b.color, flatshading: true}};
}});
Plotly.newPlot('p', traces, {{scene: {{aspectmode: 'data'}}, margin: {{l: 0, r: 0, t: 0, b: 0}}}});
document.body.dataset.firstFrameMs = performance.now().toFixed(0);
window.addEventListener('load', () => {{
  const t0 = performance.now();
  for (let k = 0; k < D.steps; k++) {{
    const xs = [], ys = [], zs = [];
    for (const b of D.bodies) {{
      const [x, y, z] = pose(b, k); xs.push(x); ys.push(y); zs.push(z);
    }}
    Plotly.restyle('p', {{x: xs, y: ys, z: zs}});
  }}
  document.body.dataset.frameMs = ((performance.now() - t0) / D.steps).toFixed(3);
}});
</script></body></html>"""


def med(xs: list[float]) -> str:
    return f"{statistics.median(xs):.1f}" if xs else "n/a"


def attr(dom: str, name: str) -> float | None:
    m = re.search(rf'data-{name}="([0-9.]+)"', dom)
    return float(m.group(1)) if m else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--deck", default="vehicle")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--plotly-outputs", type=int, default=30,
                    help="outputs the plotly page steps through (all 601 take minutes)")
    args = ap.parse_args()

    from mbsim.api import load_model, run_model
    from mbsim.output import read_result, write_result
    from mbsim.view.browser import dump_dom, find_chromium
    from mbsim.view.geometry import read_scene
    from mbsim.view.page import write_page

    if find_chromium() is None:
        sys.exit("no chromium: run .ci/browser.sh")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        spec, model = load_model(ROOT / "models" / f"{args.deck}.yaml")
        h5 = write_result(run_model(model, "dynamic", {"error_estimate": False}, deck=spec),
                          tmp / "r.h5")  # fmt: skip
        result = read_result(h5)
        three = write_page([h5], tmp / "three.html")
        probe = tmp / "three-probe.html"
        probe.write_text(three.read_text().replace("</body>", THREE_PROBE, 1))
        pages = {"three.js": (three, probe)}
        try:
            import plotly

            bundle = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
            scene = read_scene(result)
            data = {"nt": len(scene.t), "steps": min(args.plotly_outputs, len(scene.t)),
                    "bodies": [
                {"v": scene.meshes[b][0].ravel().round(6).tolist(),
                 "f": scene.meshes[b][1].ravel().tolist(),
                 "r": scene.r[:, k].ravel().round(6).tolist(),
                 "p": scene.p[:, k].ravel().round(7).tolist(),
                 "color": "#%02x%02x%02x" % tuple((scene.meshes[b][2][0] * 255).astype(int))}
                for k, b in enumerate(scene.names) if b in scene.meshes]}  # fmt: skip
            pl = tmp / "plotly.html"
            pl.write_text(PLOTLY_PAGE.format(plotly=bundle.read_text(), data=json.dumps(data)))
            pages["plotly.js"] = (pl, pl)
        except ImportError:
            print("plotly not installed: its half is skipped (pip install plotly)")
        print(f"{args.deck}: {len(result.t)} outputs, {len(read_scene(result).names)} bodies")
        print(f"{'library':<10} {'page MB':>8} {'first frame ms':>15} {'ms per output':>14}")
        for name, (page, probe_page) in pages.items():
            first, per = [], []
            for _ in range(args.repeat):
                dom = dump_dom(probe_page, timeout=900)
                first.append(attr(dom, "first-frame-ms"))
                per.append(attr(dom, "frame-ms"))
            first = [x for x in first if x is not None]
            per = [x for x in per if x is not None]
            print(f"{name:<10} {page.stat().st_size / 1e6:>8.2f} {med(first):>15} "
                  f"{med(per):>14}")


if __name__ == "__main__":
    main()
