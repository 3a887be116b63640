"""A campaign's ``report.html``: one self-contained file (figures inlined, no script or style
fetched from anywhere) with the table in the reference design's layout, the figures, every
trial in a table sortable by any column (closest approach first), and links to the flight
logs of the closest trials (``logs/trial_<index>.mcap``, re-flown from their seeds)."""

from __future__ import annotations

import base64
import html
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from uavmpc.apps.published import DEFINITION

_STYLE = """
body{font:14px/1.45 system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}
h1{font-size:1.5em}h2{font-size:1.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:3px 8px}
th{background:#f2f2f2;text-align:left}td.n{text-align:right;font-variant-numeric:tabular-nums}
#trials th{cursor:pointer;user-select:none}#trials th.sorted::after{content:" \\25B2"}
#trials th.sorted.desc::after{content:" \\25BC"}tr.hit td{background:#fde2e2}
img{max-width:100%;border:1px solid #eee}.figs{display:flex;flex-wrap:wrap;gap:1em}
.figs img{max-width:48%}code{background:#f5f5f5;padding:0 3px}
"""

# Sorts the trials table by the clicked column (numbers as numbers), ascending then descending.
_SCRIPT = """
(function(){
  var table=document.getElementById('trials'); if(!table) return;
  var heads=table.tHead.rows[0].cells, body=table.tBodies[0];
  function key(row,i){var c=row.cells[i],v=c.getAttribute('data-v');
    if(v===null) v=c.textContent; var x=parseFloat(v); return isNaN(x)?v:x;}
  function sortBy(i,desc){
    var rows=Array.prototype.slice.call(body.rows);
    rows.sort(function(a,b){var x=key(a,i),y=key(b,i);
      var r=(typeof x===typeof y)?(x<y?-1:x>y?1:0):(typeof x==='number'?-1:1);
      return desc?-r:r;});
    rows.forEach(function(r){body.appendChild(r);});
    for(var j=0;j<heads.length;j++){heads[j].className='';}
    heads[i].className='sorted'+(desc?' desc':'');
  }
  for(var i=0;i<heads.length;i++){(function(i){heads[i].addEventListener('click',function(){
    sortBy(i,heads[i].className==='sorted');});})(i);}
  sortBy(parseInt(table.getAttribute('data-sort')||'0',10),false);
})();
"""

COLUMNS = ("trial", "closest approach [m]", "collisions", "first collision [s]",
           "waypoints reached", "scenario seed", "world seed", "faults", "flight log")


def _img(path: Path) -> str:
    if not path.exists():
        return ""
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img alt="{html.escape(path.stem)}" src="data:image/png;base64,{data}">'


def _cell(text: object, sort: object = None, numeric: bool = False) -> str:
    attr = "" if sort is None else f' data-v="{html.escape(str(sort))}"'
    cls = ' class="n"' if numeric else ""
    return f"<td{cls}{attr}>{html.escape(str(text))}</td>"


def report_html(report: dict[str, Any], rows: Sequence[tuple[str, str, str]],
                beside: Sequence[tuple[str, ...]],
                trials: Sequence[dict[str, Any]], figures: Sequence[Path],
                logs: dict[int, str]) -> str:
    """The page: ``rows`` as :func:`~uavmpc.apps.campaign.report_rows` gives them, ``beside``
    the rows of :func:`~uavmpc.apps.published.comparison_rows` (none: no such section),
    ``trials`` the records, ``figures`` PNG files to inline, ``logs`` trial index → relative
    path of its flight log."""
    esc = html.escape
    table = ["<table><tr><th>random_walk</th><th>without avoidance</th>"
             "<th>with avoidance</th></tr>"]
    table += [f"<tr><th>{esc(n)}</th><td>{esc(a)}</td><td>{esc(b)}</td></tr>"
              for n, a, b in rows]
    table.append("</table>")
    body_rows = []
    for r in trials:
        i = int(r["index"])
        log = logs.get(i)
        link = (f'<td><a href="{esc(log)}">{esc(Path(log).name)}</a></td>' if log
                else "<td></td>")
        wp = (f"{r['waypoints_reached']} / {r['waypoints_due']}" if "waypoints_due" in r
              else "–")
        faults = r.get("faults")
        first = r.get("first_collision_s")
        cls = ' class="hit"' if r["collisions"] else ""
        body_rows.append(
            f"<tr{cls}>" + _cell(i, i, True)
            + _cell(f"{r['min_distance_m']:.2f}", r["min_distance_m"], True)
            + _cell(r["collisions"], r["collisions"], True)
            + _cell("–" if first is None else f"{first:.1f}",
                    "" if first is None else first, True)
            + _cell(wp, r.get("waypoints_reached", ""), True)
            + _cell(r["scenario_seed"], r["scenario_seed"], True)
            + _cell(r["world_seed"], r["world_seed"], True)
            + _cell(json.dumps(faults, separators=(",", ":")) if faults else "")
            + link + "</tr>")
    p = report["parameters"]
    title = (f"random_walk campaign, {'with' if report['avoidance'] else 'without'} "
             f"avoidance: {report['trials']} trials, {report['simulated_hours']:.1f} h")
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{esc(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{esc(title)}</h1>",
        "<p>A collision is a 3-D distance between centres below 1 m. Percentiles are those of "
        "the empirical CDF over all trials; a trial without collision counts as later than "
        "its length (\"&gt; …\").</p>",
    ]
    parts += table
    if beside:
        ref = report["reference"]
        parts += [f"<h2>Beside the {esc(ref['name'])}</h2>",
                  f"<p>Source: {esc(ref['source'])}. Its set-up: {esc(ref['setup'])}. "
                  f"{esc(DEFINITION)}</p>",
                  "<table><tr><th>random_walk</th><th>ours</th><th>our 95 % interval</th>"
                  "<th>published</th><th>published inside ours?</th></tr>"]
        parts += ["<tr><th>" + esc(r[0]) + "</th>" + "".join(f"<td>{esc(c)}</td>" for c in r[1:])
                  + "</tr>" for r in beside]
        parts.append("</table>")
    parts += ["<h2>Figures</h2>", '<div class="figs">']
    parts += [_img(f) for f in figures]
    parts += ["</div>",
              f"<h2>Every trial ({len(trials)}; click a column to sort)</h2>",
              f"<p>{p['uavs']} UAVs over {p['area_m']:g} m × {p['area_m']:g} m. The flight "
              f"logs of the {len(logs)} closest trials are re-flown from their seeds and open "
              "in Foxglove with <code>docs/foxglove_layout.json</code>.</p>",
              '<table id="trials" data-sort="1"><thead><tr>'
              + "".join(f"<th>{esc(c)}</th>" for c in COLUMNS) + "</tr></thead><tbody>"]
    parts += body_rows
    parts += ["</tbody></table>", f"<script>{_SCRIPT}</script>", "</body></html>"]
    return "\n".join(parts) + "\n"
