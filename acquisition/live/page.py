"""The live view's page: one HTML document with its style and script inline (the bench's computer may have no
internet; nothing is fetched but ``state.json`` from the same server). It polls ``state.json`` every second and
draws the slice as it grows as inline SVG: f_r (1/sr, the mean of the channels for a spectrometer) against
theta_o per incidence, each sample with its error bar (+- one standard deviation of the mean), a linear or
logarithmic f_r axis; and beside it the status, the points done and planned, the time left and the last sample.
"""

from __future__ import annotations

__all__ = ["PAGE"]

PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>gonio-capture: live view</title>
<style>
 body { font: 14px/1.4 system-ui, sans-serif; margin: 16px 24px; color: #222; background: #fafafa; }
 h1 { font-size: 18px; margin: 0 0 8px; }
 #facts { display: flex; gap: 28px; flex-wrap: wrap; margin: 6px 0 10px; }
 #facts div b { display: block; font-size: 12px; color: #666; font-weight: normal; }
 #facts div span { font-size: 17px; }
 #status.complete { color: #176b2c; } #status.failed, #status.stale { color: #a3191b; }
 svg { background: #fff; border: 1px solid #ddd; }
 .axis { stroke: #444; stroke-width: 1; } .grid { stroke: #eee; stroke-width: 1; }
 .tick { font-size: 11px; fill: #444; } .errbar { stroke-width: 1; }
 #legend span { display: inline-block; margin-right: 16px; }
 #legend i { display: inline-block; width: 12px; height: 12px; margin-right: 4px; vertical-align: -1px; }
</style></head>
<body>
<h1>Live capture <span id="folder"></span></h1>
<div id="facts">
 <div><b>status</b><span id="status">connecting</span></div>
 <div><b>points</b><span id="done">0</span> / <span id="total">?</span></div>
 <div><b>time left</b><span id="left">?</span></div>
 <div><b>last sample</b><span id="current">none yet</span></div>
 <div><b>updated</b><span id="updated">-</span></div>
</div>
<label><input type="checkbox" id="log"> logarithmic f<sub>r</sub></label>
<div id="legend"></div>
<svg id="plot" width="1100" height="560" viewBox="0 0 1100 560" role="img"
     aria-label="f_r against theta_o per incidence"></svg>
<p id="note"></p>
<script>
"use strict";
const NS = "http://www.w3.org/2000/svg";
const COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2"];
const W = 1100, H = 560, L = 70, R = 20, T = 20, B = 50;
let last = null, failures = 0, ended = false;
function fmtTime(s) {
  if (s === null || s === undefined || !isFinite(s)) return "?";
  if (s < 90) return s.toFixed(0) + " s";
  if (s < 5400) return (s / 60).toFixed(1) + " min";
  return (s / 3600).toFixed(1) + " h";
}
function el(name, attrs, parent) {
  const e = document.createElementNS(NS, name);
  for (const k in attrs) e.setAttribute(k, attrs[k]);
  if (parent) parent.appendChild(e);
  return e;
}
function draw(st) {
  const svg = document.getElementById("plot");
  while (svg.firstChild) svg.removeChild(svg.firstChild);
  const logy = document.getElementById("log").checked;
  const pts = st.samples;
  let lo = Infinity, hi = -Infinity;
  for (const p of pts) {
    const a = logy ? Math.max(p[2] - p[3], p[2] * 0.5) : p[2] - p[3], b = p[2] + p[3];
    if (!logy || a > 0) lo = Math.min(lo, a);
    hi = Math.max(hi, b);
  }
  if (!isFinite(lo) || !isFinite(hi)) { lo = logy ? 1e-3 : 0; hi = 1; }
  if (!logy) { lo = Math.min(0, lo); hi = hi + 0.05 * (hi - lo); }
  if (logy) { lo = Math.max(lo, hi * 1e-6); lo = Math.pow(10, Math.floor(Math.log10(lo)));
              hi = Math.pow(10, Math.ceil(Math.log10(hi))); }
  if (hi <= lo) hi = lo + 1;
  const x = t => L + (t + 90) / 180 * (W - L - R);
  const y = v => logy ? T + (Math.log10(hi) - Math.log10(Math.max(v, lo))) / (Math.log10(hi) - Math.log10(lo))
                        * (H - T - B) : T + (hi - v) / (hi - lo) * (H - T - B);
  for (let t = -90; t <= 90; t += 15) {
    el("line", {x1: x(t), x2: x(t), y1: T, y2: H - B, class: "grid"}, svg);
    el("text", {x: x(t), y: H - B + 16, "text-anchor": "middle", class: "tick"}, svg).textContent = t;
  }
  const ticks = [];
  if (logy) { for (let e = Math.log10(lo); e <= Math.log10(hi) + 1e-9; e++) ticks.push(Math.pow(10, e)); }
  else { const step = Math.pow(10, Math.floor(Math.log10((hi - lo) / 4)));
         const k = (hi - lo) / step > 20 ? 5 : (hi - lo) / step > 8 ? 2 : 1;
         for (let v = Math.ceil(lo / (k * step)) * k * step; v <= hi + 1e-12; v += k * step) ticks.push(v); }
  for (const v of ticks) {
    el("line", {x1: L, x2: W - R, y1: y(v), y2: y(v), class: "grid"}, svg);
    el("text", {x: L - 6, y: y(v) + 4, "text-anchor": "end", class: "tick"}, svg).textContent =
      Math.abs(v) >= 1e4 || (Math.abs(v) < 1e-2 && v !== 0) ? v.toExponential(0) : +v.toPrecision(3);
  }
  el("line", {x1: L, x2: W - R, y1: H - B, y2: H - B, class: "axis"}, svg);
  el("line", {x1: L, x2: L, y1: T, y2: H - B, class: "axis"}, svg);
  el("text", {x: (L + W - R) / 2, y: H - 10, "text-anchor": "middle", class: "tick"}, svg).textContent =
    "theta_o (degrees)";
  el("text", {x: 16, y: (T + H - B) / 2, transform: `rotate(-90 16 ${(T + H - B) / 2})`, "text-anchor": "middle",
              class: "tick"}, svg).textContent = "f_r (1/sr)";
  const groups = new Map();
  for (const p of pts) { const k = String(p[0]); if (!groups.has(k)) groups.set(k, []); groups.get(k).push(p); }
  const legend = document.getElementById("legend");
  legend.textContent = "";
  let i = 0;
  for (const [ti, list] of groups) {
    const c = COLOURS[i++ % COLOURS.length];
    const g = el("g", {class: "incidence", "data-theta-i": ti}, svg);
    list.sort((a, b) => a[1] - b[1]);
    el("polyline", {points: list.map(p => `${x(p[1])},${y(p[2])}`).join(" "), fill: "none", stroke: c,
                    "stroke-width": 1.5, "stroke-opacity": 0.6}, g);
    for (const p of list) {
      el("line", {x1: x(p[1]), x2: x(p[1]), y1: y(p[2] - p[3]), y2: y(p[2] + p[3]), stroke: c, class: "errbar"}, g);
      const s = el("circle", {cx: x(p[1]), cy: y(p[2]), r: 3.2, fill: c, class: "sample",
                              "data-theta-o": p[1], "data-f": p[2]}, g);
      el("title", {}, s).textContent = `theta_i ${p[0]}, theta_o ${p[1]}: f_r ${p[2].toPrecision(4)} +- ` +
                                        `${p[3].toPrecision(2)} /sr`;
    }
    const item = document.createElement("span");
    item.innerHTML = `<i style="background:${c}"></i>`;
    item.appendChild(document.createTextNode(`theta_i = ${ti} deg (${list.length})`));
    legend.appendChild(item);
  }
}
function show(st) {
  const pr = st.progress || {};
  document.getElementById("folder").textContent = st.folder ? "(" + st.folder + ")" : "";
  const status = pr.status || st.record.status || "starting";
  const se = document.getElementById("status");
  se.textContent = status + (pr.message ? ": " + pr.message : "");
  se.className = status;
  document.getElementById("done").textContent = pr.points_done !== undefined ? pr.points_done : st.samples.length;
  document.getElementById("total").textContent = pr.points_total || "?";
  document.getElementById("left").textContent = status === "complete" ? "0 s" : fmtTime(pr.time_left_s);
  const c = pr.last;
  document.getElementById("current").textContent = c ? `(${c.theta_i_deg}, ${c.theta_o_deg}) deg: f_r ` +
    `${c.f_r.toPrecision(4)} +- ${c.std.toPrecision(2)} /sr, ${c.repeats} repeats` : "none yet";
  document.getElementById("updated").textContent = new Date().toLocaleTimeString();
  document.getElementById("note").textContent = st.channels > 1 ?
    `f_r is the mean of the ${st.channels} channels.` : "";
  draw(st);
  if (status === "complete" || status === "failed" || status === "interrupted") ended = true;
}
async function poll() {
  try {
    const r = await fetch("state.json", {cache: "no-store"});
    if (!r.ok) throw new Error(r.status);
    last = await r.json();
    failures = 0;
    show(last);
  } catch (e) {
    failures += 1;
    if (failures >= 2) {
      const se = document.getElementById("status");
      se.textContent = ended ? se.textContent + " (the live view has stopped)" :
        "no answer: the capture has ended, or the live view stopped";
      se.className = ended ? se.className : "stale";
      if (ended) return;
    }
  }
  setTimeout(poll, 1000);
}
document.getElementById("log").addEventListener("change", () => { if (last) draw(last); });
poll();
</script>
</body></html>
"""
