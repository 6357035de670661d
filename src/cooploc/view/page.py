"""The self-contained HTML page of the viewer.

One file: plotly.js is embedded (``include_plotlyjs=True``), nothing is fetched, so
the page opens offline from disk. Around the figure the page states the run, the
scenario and every size limit that thinned the drawing (`FrameData.notes`).

Two hooks make the page checkable by a headless browser (``tests/test_view_browser.py``):
a script in ``<head>``, installed before plotly.js runs, records every uncaught error
and unhandled promise rejection into ``<pre id="cooploc-errors">``; after the load
event, ``<pre id="cooploc-status">`` receives JSON with the names of the traces
plotly drew, the number of animation frames and the milliseconds since navigation
start. ``page.html#step=K`` opens the page at step K (the last frame at or before
it), ``page.html#x=x0,x1&y=y0,y1`` with the map zoomed to that box (m); both combine
(``#step=K&x=…``).
"""

from __future__ import annotations

import html
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["DIV_ID", "write_page"]

DIV_ID = "cooploc-view"

_HEAD_SCRIPT = """<script>
(function () {
  var errors = [];
  function show() {
    var el = document.getElementById('cooploc-errors');
    if (el) { el.textContent = JSON.stringify(errors); }
  }
  window.addEventListener('error', function (e) {
    errors.push(String(e.message || e.type) + ' @ ' + (e.filename || '') + ':' + (e.lineno || 0));
    show();
  });
  window.addEventListener('unhandledrejection', function (e) {
    errors.push('unhandled rejection: ' + String(e.reason)); show();
  });
  document.addEventListener('DOMContentLoaded', show);
})();
</script>"""

_STATUS_SCRIPT = r"""<script>
window.addEventListener('load', function () {
  setTimeout(function () {
    var gd = document.getElementById('%(div)s');
    var drawn = !!(gd && gd.data && gd._fullLayout);
    var frames = drawn && gd._transitionData ? gd._transitionData._frames.length : 0;
    var wanted = /step=(\d+)/.exec(window.location.hash);
    if (drawn && wanted && frames) {  // page.html#step=K opens at the last frame at or before step K
      var names = gd._transitionData._frames.map(function (f) { return Number(f.name); });
      var name = names.filter(function (k) { return k <= Number(wanted[1]); }).pop();
      Plotly.animate(gd, [String(name === undefined ? names[0] : name)],
                     {mode: 'immediate', frame: {duration: 0, redraw: false}, transition: {duration: 0}});
    }
    var zoom = /x=(-?[\d.]+),(-?[\d.]+)&y=(-?[\d.]+),(-?[\d.]+)/.exec(window.location.hash);
    if (drawn && zoom) {  // page.html#x=x0,x1&y=y0,y1 opens the map zoomed to that box (m)
      Plotly.relayout(gd, {'xaxis.range': [Number(zoom[1]), Number(zoom[2])],
                           'yaxis.range': [Number(zoom[3]), Number(zoom[4])]});
    }
    document.getElementById('cooploc-status').textContent = JSON.stringify({
      rendered: drawn, ms: Math.round(performance.now()), frames: frames,
      traces: drawn ? gd.data.map(function (t) { return t.name; }) : []
    });
  }, 0);
});
</script>"""

_STYLE = """<style>
body { font-family: system-ui, sans-serif; margin: 0.6em 1.2em; color: #222; }
h1 { font-size: 1.2em; margin: 0.2em 0; }
p.meta { margin: 0.2em 0; color: #555; font-size: 0.9em; }
div.notes { background: #fff6d5; border: 1px solid #e8d48a; padding: 0.3em 0.7em; font-size: 0.85em; }
pre.hook { display: none; }
</style>"""


def write_page(fig: Any, path: str | os.PathLike[str], title: str, meta: Sequence[str],
               notes: Sequence[str]) -> Path:
    """Write the figure as one offline HTML page with the run's `meta` lines and `notes`."""
    body = fig.to_html(full_html=False, include_plotlyjs=True, div_id=DIV_ID, auto_play=False,
                       default_width="100%", default_height="86vh",
                       config={"displaylogo": False, "responsive": True, "scrollZoom": True})
    lines = "".join(f'<p class="meta">{html.escape(m)}</p>' for m in meta)
    box = ""
    if notes:
        items = "".join(f"<li>{html.escape(n)}</li>" for n in notes)
        box = f'<div class="notes">Thinned to stay responsive:<ul>{items}</ul></div>'
    page = (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title>{_HEAD_SCRIPT}{_STYLE}</head><body>"
            f"<h1>{html.escape(title)}</h1>{lines}{box}"
            f'<pre id="cooploc-errors" class="hook">[]</pre><pre id="cooploc-status" class="hook"></pre>'
            f"{body}{_STATUS_SCRIPT % {'div': DIV_ID}}</body></html>\n")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(page, encoding="utf-8")
    return out
