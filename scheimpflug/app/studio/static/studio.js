// scheimpflug studio: the page. Plain ES module, SVG, no framework, nothing from the internet.
// Every figure comes from the server (GET /api/studio, the engine of `scheimpflug design`); this file
// builds the controls from the key table (GET /api/keys), sends the rig on every `input` event (the
// newest request wins: older ones are aborted, late answers dropped) and draws what comes back.

const $ = (id) => document.getElementById(id);
const SVGNS = "http://www.w3.org/2000/svg";

const state = {
  keys: [],            // the key table
  byName: new Map(),   // name → key
  preset: null,        // preset=NAME, or null for the studio's own rig
  set: new Map(),      // rig keys set by the user: name → text (empty text: left out, derived)
  subpixel: "1",
  last: null,          // the newest answer drawn
  baseline: null,      // {answer, query} when pinned
  seq: 0,              // newest input
  drawn: 0,            // newest input drawn
  inflight: false,     // a request on its way
  wantT0: 0,           // time stamp of the newest input
  lastKey: null,       // the control that changed last (where a message without a key is shown)
  occ: { on: false, part: "cylinder", angle: 0, inflight: false, want: 0, done: 0, last: null, turn: null },
  preview: { on: false, inflight: false, want: 0, done: 0, url: null },
};

const OCC_COLOURS = { seen: "#2ca02c", out_of_view: "#999999", camera_shadow: "#9467bd", laser_shadow: "#8c564b",
  unreached: "#dddddd" };
const OCC_NAMES = { seen: "seen", out_of_view: "out of view", camera_shadow: "camera shadow",
  laser_shadow: "laser shadow", unreached: "neither (far side)" };

// latency record for the benchmark and the tests: one entry per drawn answer
window.studio = { state, latencies: [], inputs: [], errors: 0, drawnSeq: 0 };

// ------------------------------------------------------------------ query

function query(extra = {}) {
  const p = new URLSearchParams();
  const preset = "preset" in extra ? extra.preset : state.preset;
  if (preset) p.set("preset", preset);
  if (state.subpixel && state.subpixel !== "1") p.set("subpixel", state.subpixel);
  for (const [name, text] of state.set) p.set(name, text);
  return p.toString();
}

function readLocation() {
  const p = new URLSearchParams(location.search);
  for (const [name, text] of p) {
    if (name === "preset") state.preset = text;
    else if (name === "subpixel") state.subpixel = text;
    else state.set.set(name, text);
  }
}

// ------------------------------------------------------------------ controls

function parseRange(text) {
  const m = /^([[(])\s*([^,]+),\s*([^\])]+)([\])])$/.exec(text || "");
  if (!m) return null;
  return { lo: Number(m[2]), hi: Number(m[3]), loOpen: m[1] === "(", hiOpen: m[4] === ")" };
}

function sliderSpan(k, v) {
  const r = parseRange(k.range) || { lo: -1e9, hi: 1e9 };
  let lo, hi;
  if (r.lo >= 0 && v > 0) { lo = v / 3; hi = v * 3; }
  else { const w = 2 * Math.max(Math.abs(v), 1); lo = v - w; hi = v + w; }
  lo = Math.max(lo, r.lo); hi = Math.min(hi, r.hi);
  if (k.type === "int") { lo = Math.ceil(lo); hi = Math.floor(hi); }
  return [lo, hi];
}

function tooltip(k) {
  return `${k.name} [${k.unit || "-"}], range ${k.range}${k.derived ? ", derived when left out" : ""}\n\n${k.description}`;
}

function buildControl(k, parent) {
  const div = document.createElement("div");
  div.className = "ctl";
  div.id = `ctl-${k.name}`;
  div.title = tooltip(k);
  const numeric = k.type === "int" || k.type === "float";
  div.innerHTML = `<label><span class="name">${k.key}</span><span><span class="unit">${k.unit && k.unit !== "-" ? k.unit : ""}</span>
    <span class="tag"></span></span></label><div class="inputs"></div><div class="why"></div><div class="warn"></div>`;
  const inputs = div.querySelector(".inputs");
  let slider = null;
  if (numeric && k.main) {
    slider = document.createElement("input");
    slider.type = "range";
    slider.name = k.name;
    slider.setAttribute("aria-label", `${k.name} slider`);
    inputs.append(slider);
    slider.addEventListener("input", (ev) => {
      text.value = k.type === "int" ? String(Math.round(Number(slider.value))) : Number(slider.value).toPrecision(6).replace(/\.?0+$/, "");
      changed(k, text.value, ev.timeStamp);
    });
  }
  const text = document.createElement("input");
  text.type = "text";
  text.name = k.name;
  text.setAttribute("aria-label", k.name);
  text.spellcheck = false;
  inputs.append(text);
  text.addEventListener("input", (ev) => {
    const v = Number(text.value);
    if (slider && text.value.trim() !== "" && Number.isFinite(v)) {
      if (v < Number(slider.min) || v > Number(slider.max)) setSpan(k, slider, v);
      slider.value = String(v);
    }
    changed(k, text.value.trim(), ev.timeStamp);
  });
  parent.append(div);
  k.el = { div, slider, text, spanSet: false };
}

function setSpan(k, slider, v) {
  const [lo, hi] = sliderSpan(k, v);
  slider.min = String(lo);
  slider.max = String(hi);
  slider.step = k.type === "int" ? "1" : String((hi - lo) / 1000);
  k.el.spanSet = true;
}

function buildControls() {
  for (const [parent, main] of [[$("main-keys"), true], [$("more-keys"), false]]) {
    let table = null;
    for (const k of state.keys.filter((k) => k.main === main)) {
      if (k.table !== table) {
        table = k.table;
        parent.insertAdjacentHTML("beforeend", `<div class="table-head">[${table}]</div>`);
      }
      buildControl(k, parent);
    }
  }
}

function changed(k, text, t0) {
  state.set.set(k.name, text);
  state.lastKey = k.name;
  request(t0);
}

function showValues(answer) {
  const active = document.activeElement;
  for (const k of state.keys) {
    const v = answer.rig[k.table][k.key];
    const el = k.el;
    if (el.text !== active) el.text.value = v === null ? "" : String(v);
    if (el.slider && typeof v === "number") {
      if (!el.spanSet) setSpan(k, el.slider, v);
      if (el.slider !== active) el.slider.value = String(v);
    }
    el.div.querySelector(".tag").textContent = answer.derived.includes(k.name) ? "(derived)" : "";
  }
}

// ------------------------------------------------------------------ requests: the newest wins
// One request on its way at a time. Inputs that come meanwhile only move the wanted state on; when the
// answer arrives it is drawn (if no newer one was drawn) and the newest state is asked for at once. So
// the views follow a moving slider at the server's pace and no queue grows, however fast the inputs.

function request(t0 = performance.now()) {
  const seq = ++state.seq;
  window.studio.inputs.push({ seq, t0 });
  if (window.studio.inputs.length > 5000) window.studio.inputs.splice(0, 1000);
  state.wantT0 = t0;
  if (!state.inflight) send();
}

async function send() {
  state.inflight = true;
  const seq = state.seq, t0 = state.wantT0, q = query(), tSend = performance.now();
  let resp = null, body = null;
  for (let attempt = 0; attempt < 20; attempt++) {
    try {
      resp = await fetch(`/api/studio?${q}`);
      body = await resp.json();
    } catch (err) {
      state.inflight = false;
      pageError(`the studio does not answer (${err.message}): is it still running?`);
      return;
    }
    if (resp.status !== 503) break;
    await new Promise((r) => setTimeout(r, 50));
  }
  state.inflight = false;
  if (seq > state.drawn) {
    state.drawn = seq;
    state.fetchMs = performance.now() - tSend;
    if (resp.ok) draw(body, q, seq, t0);
    else refused(body, seq);
  }
  if (state.seq > seq) send();
}

function refused(body, seq) {
  window.studio.errors += 1;
  clearMarks();
  const name = body.key && state.byName.has(body.key) ? body.key : state.lastKey;
  const k = name ? state.byName.get(name) : null;
  if (k) {
    k.el.div.classList.add("bad");
    k.el.div.querySelector(".why").textContent = body.error;
    if (name !== state.lastKey && state.lastKey) {
      const last = state.byName.get(state.lastKey);
      last.el.div.classList.add("bad");
      last.el.div.querySelector(".why").textContent = `the rig is refused: ${body.error}`;
    }
  } else {
    pageError(body.error);
  }
  $("status").textContent = "not a rig: the last good design is shown";
  window.studio.drawnSeq = seq;
  document.body.dataset.seq = String(seq);
  document.body.dataset.state = "refused";
}

function pageError(text) {
  const el = $("page-error");
  el.textContent = text;
  el.hidden = !text;
}

function clearMarks() {
  for (const k of state.keys) {
    k.el.div.classList.remove("bad");
    k.el.div.querySelector(".why").textContent = "";
    k.el.div.querySelector(".warn").textContent = "";
  }
  pageError("");
}

// ------------------------------------------------------------------ drawing

function draw(answer, q, seq, t0) {
  const tDraw = performance.now();
  state.last = answer;
  state.lastQuery = q;
  clearMarks();
  showValues(answer);
  for (const w of answer.warnings) {
    const k = w.key && state.byName.get(w.key);
    if (k) k.el.div.querySelector(".warn").textContent = w.message;
  }
  $("rig-label").textContent = answer.label + (state.set.size ? " with changes" : "");
  drawMeridian(answer);
  drawField(answer);
  drawDatasheet(answer);
  drawCurves(answer);
  drawFocusMap(answer);
  drawPlans(answer);
  exports(q);
  addressShows(q);
  occlusionRequest();
  const t1 = performance.now();
  requestAnimationFrame(() => {
    const t2 = performance.now();
    window.studio.latencies.push({ seq, ms: t2 - t0, fetch_ms: state.fetchMs, draw_ms: t1 - tDraw, at: t2 });
    if (window.studio.latencies.length > 5000) window.studio.latencies.splice(0, 1000);
    $("status").textContent = `redrawn in ${(t2 - t0).toFixed(0)} ms`;
  });
  window.studio.drawnSeq = seq;
  document.body.dataset.seq = String(seq);
  document.body.dataset.state = "drawn";
}

// The page's address shows the design (it is the link), at most every 250 ms: browsers throttle
// history.replaceState called on every input event of a drag.
function addressShows(q) {
  state.address = q;
  if (state.addressTimer) return;
  state.addressTimer = setTimeout(() => {
    state.addressTimer = null;
    history.replaceState(null, "", state.address ? `?${state.address}` : location.pathname);
  }, 250);
}

function el(tag, attrs, parent) {
  const e = document.createElementNS(SVGNS, tag);
  for (const [a, v] of Object.entries(attrs)) e.setAttribute(a, v);
  if (parent) parent.append(e);
  return e;
}

function text(parent, x, y, s, attrs = {}) {
  const t = el("text", { x, y, ...attrs }, parent);
  if (attrs.fill) t.style.fill = attrs.fill;       // the page's CSS would win over the attribute
  t.textContent = s;
  return t;
}

// A world → screen map, equal scales (to scale), y up.
function frame(svg, pts, pad = 24, padY = pad) {
  const vb = svg.viewBox.baseVal;
  const xs = pts.map((p) => p[0]).filter(Number.isFinite), ys = pts.map((p) => p[1]).filter(Number.isFinite);
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const s = Math.min((vb.width - 2 * pad) / Math.max(x1 - x0, 1e-9), (vb.height - 2 * padY) / Math.max(y1 - y0, 1e-9));
  const ox = pad + (vb.width - 2 * pad - s * (x1 - x0)) / 2, oy = padY + (vb.height - 2 * padY - s * (y1 - y0)) / 2;
  const f = (p) => [ox + s * (p[0] - x0), vb.height - oy - s * (p[1] - y0)];
  f.scale = s;
  return f;
}

function line(g, f, a, b, attrs) {
  const [x1, y1] = f(a), [x2, y2] = f(b);
  return el("line", { x1, y1, x2, y2, ...attrs }, g);
}

function poly(g, f, pts, attrs, closed = false) {
  const d = pts.map(f).map(([x, y]) => `${x.toFixed(2)},${y.toFixed(2)}`).join(" ");
  return el(closed ? "polygon" : "polyline", { points: d, fill: "none", ...attrs }, g);
}

function extend(a, b, t) { return [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]; }

function drawRig(svg, m, f, base, labels) {
  const S = { sheet: "#1f77b4", sensor: "#d62728", sharp: "#ff7f0e", hinge: "#2ca02c" };
  if (base) {
    const bm = base.views.meridian;
    poly(svg, f, bm.wedge, { stroke: "#888", "stroke-dasharray": "3 3", fill: "none" }, true);
    line(svg, f, bm.range[0], bm.range[1], { stroke: "#888", "stroke-width": 6, opacity: 0.35 });
    line(svg, f, bm.sensor[0], bm.sensor[1], { stroke: "#888", "stroke-width": 4, opacity: 0.6 });
  }
  const yl = [Math.min(m.sensor[0][1], m.sensor[1][1], m.lens[0][1]) - 20, Math.max(m.scheimpflug_point[1], m.laser[1]) + 20];
  line(svg, f, [0, yl[0]], [0, yl[1]], { stroke: "#000", "stroke-width": 0.6 });                 // lens plane
  line(svg, f, [m.focal_length_mm, yl[0]], [m.focal_length_mm, yl[1]], { stroke: "#999", "stroke-dasharray": "2 3" });
  line(svg, f, [-m.focal_length_mm, yl[0]], [-m.focal_length_mm, yl[1]], { stroke: "#999", "stroke-dasharray": "2 3" });
  line(svg, f, [Math.min(m.sensor[0][0], m.sensor[1][0]) - 5, 0], [m.sheet[1][0], 0], { stroke: "#666", "stroke-dasharray": "8 3 2 3", "stroke-width": 0.6 });
  poly(svg, f, m.wedge, { fill: S.sharp, "fill-opacity": 0.28, stroke: S.sharp, "stroke-width": 0.5 }, true);
  line(svg, f, m.sheet[0], m.sheet[1], { stroke: S.sheet, "stroke-width": 1.4 });
  line(svg, f, m.range[0], m.range[1], { stroke: S.sheet, "stroke-width": 7, opacity: 0.45 });
  // chief rays of the sensor's ends
  for (let i = 0; i < 2; i++) line(svg, f, m.sensor[i], m.range[i], { stroke: "#999", "stroke-width": 0.5 });
  // the plane of sharp focus, from the Scheimpflug point through the sharp segment
  line(svg, f, m.scheimpflug_point, extend(m.sharp[0], m.sharp[1], 1.1), { stroke: S.sharp, "stroke-width": 1, "stroke-dasharray": "6 3" });
  // the sensor plane to the Scheimpflug point, the hinge rule O→H ∥ sensor
  line(svg, f, m.sensor[0], m.scheimpflug_point, { stroke: S.sensor, "stroke-width": 0.6, "stroke-dasharray": "4 3" });
  line(svg, f, [0, 0], extend([0, 0], m.object_hinge, 1.4), { stroke: S.hinge, "stroke-width": 1, "stroke-dasharray": "5 3" });
  line(svg, f, m.lens[0], m.lens[1], { stroke: "#000", "stroke-width": 4 });
  line(svg, f, m.sensor[0], m.sensor[1], { stroke: S.sensor, "stroke-width": 5 });
  const [ax, ay] = f(m.axis);
  el("circle", { cx: ax, cy: ay, r: 3, fill: "#444" }, svg);
  if (labels.part) el("circle", { cx: ax, cy: ay, r: labels.part * f.scale, fill: "none", stroke: "#444", "stroke-dasharray": "2 2" }, svg);
  if (labels.axis) text(svg, ax + 5, ay - 5, "rotary axis");
  for (const [p, name] of [[m.scheimpflug_point, "O′ Scheimpflug line"], [m.object_hinge, "H hinge line"], [m.image_hinge, "H′"], [[0, 0], "O"]]) {
    const [x, y] = f(p);
    el("circle", { cx: x, cy: y, r: 2.5, fill: "#000" }, svg);
    const right = x > labels.width - 100;     // near the right edge: the label to the left of its point
    if (labels.points) text(svg, right ? x - 4 : x + 4, name.startsWith("H ") ? y + 13 : y - 4, name,
      right ? { "text-anchor": "end" } : {});
  }
}

function drawMeridian(answer) {
  const m = answer.views.meridian;
  const base = state.baseline && state.baseline.answer;
  for (const [id, zoom] of [["meridian", false], ["zoom", true]]) {
    const svg = $(id);
    svg.replaceChildren();
    let pts;
    if (zoom) {
      const fl = m.focal_length_mm;
      pts = [...m.sensor, ...m.lens, m.scheimpflug_point, m.object_hinge, m.image_hinge, [fl * 1.3, 0], [-fl * 1.3, 0]];
    } else {
      pts = [...m.sensor, ...m.lens, ...m.sheet, ...m.range, m.scheimpflug_point, m.object_hinge, m.axis];
      if (base) pts.push(...base.views.meridian.range, ...base.views.meridian.sensor);
    }
    const f = frame(svg, pts);
    const clip = `clip-${id}`;
    const defs = el("defs", {}, svg);
    const vb = svg.viewBox.baseVal;
    el("rect", { x: 0, y: 0, width: vb.width, height: vb.height }, el("clipPath", { id: clip }, defs));
    const g = el("g", { "clip-path": `url(#${clip})` }, svg);
    drawRig(g, m, f, base, { points: true, axis: !zoom, part: zoom ? 0 : answer.design.rotary_plan.part_radius_mm,
      width: vb.width });
    scaleBar(svg, f, zoom ? "lens and sensor" : "");
  }
}

function scaleBar(svg, f, title) {
  const vb = svg.viewBox.baseVal;
  const target = 120 / f.scale;
  const mag = 10 ** Math.floor(Math.log10(target));
  const len = [1, 2, 5, 10].map((k) => k * mag).filter((v) => v <= target).pop() || mag;
  const x = 10, y = vb.height - 10;
  el("line", { x1: x, y1: y, x2: x + len * f.scale, y2: y, stroke: "#000", "stroke-width": 2 }, svg);
  text(svg, x, y - 5, `${len} mm`);
  if (title) text(svg, 10, 14, title);
}

function drawField(answer) {
  const svg = $("field");
  svg.replaceChildren();
  const v = answer.views.field;
  const base = state.baseline && state.baseline.answer.views.field;
  const pts = [...v.trapezoid, [v.axis_d_mm, v.rotary_table_z_mm]];
  if (base) pts.push(...base.trapezoid);
  const f = frame(svg, pts, 90, 34);
  state.fieldFrame = f;
  if (base) poly(svg, f, base.trapezoid, { stroke: "#888", "stroke-dasharray": "4 3" }, true);
  poly(svg, f, v.trapezoid, { fill: "#1f77b4", "fill-opacity": 0.15, stroke: "#1f77b4", "stroke-width": 1.5 }, true);
  const tz = v.trapezoid;
  const hMin = Math.min(...tz.map((p) => p[1])), hMax = Math.max(...tz.map((p) => p[1]));
  line(svg, f, [v.axis_d_mm, hMin], [v.axis_d_mm, hMax], { stroke: "#444", "stroke-dasharray": "5 3" });
  line(svg, f, [tz[0][0], v.rotary_table_z_mm], [tz[1][0], v.rotary_table_z_mm], { stroke: "#8c564b", "stroke-width": 1 });
  line(svg, f, [tz[0][0], 0], [tz[1][0], 0], { stroke: "#bbb", "stroke-dasharray": "2 3" });
  const [ax, ay] = f([v.axis_d_mm, hMax]);
  text(svg, ax + 3, ay + 12, "rotary axis");
  const [tx, ty] = f([tz[1][0], v.rotary_table_z_mm]);
  text(svg, tx - 70, ty + 12, "rotary table");
  const d = answer.design;
  const [n0x, n0y] = f(tz[0]), [f0x, f0y] = f(tz[1]);
  text(svg, n0x, n0y - 6, `near D = ${d.distance_range_mm[0].toFixed(1)}`, { "text-anchor": "end" });
  text(svg, f0x, f0y - 6, `far D = ${d.distance_range_mm[1].toFixed(1)}`, { "text-anchor": "start" });
  const [bx, by] = f(tz[3]);
  text(svg, bx, by + 14, `X near ${d.height_range_near_mm.toFixed(1)} mm`, { "text-anchor": "end" });
  const [cx, cy] = f(tz[2]);
  text(svg, cx, cy + 14, `X far ${d.height_range_far_mm.toFixed(1)} mm`, { "text-anchor": "start" });
  const rows = Object.fromEntries(answer.views.datasheet.map((r) => [r.key, r.value]));
  text(svg, 8, 14, `range Z ${d.depth_range_mm.toFixed(1)} mm · clearance from the laser exit ${rows.clearance_mm.toFixed(1)} mm`);
  if (state.occ.on && state.occ.last) drawOcclusionPoints(state.occ.last);
}

function fmt(v, unit) {
  if (v === null || v === undefined) return "–";
  const a = Math.abs(v);
  const digits = unit === "-" ? 3 : a >= 1000 ? 1 : a >= 100 ? 2 : a >= 10 ? 3 : 4;
  return v.toFixed(Math.max(0, digits - (a >= 1000 ? 1 : 0)));
}

function drawDatasheet(answer) {
  const t = $("datasheet");
  const base = state.baseline && Object.fromEntries(state.baseline.answer.views.datasheet.map((r) => [r.key, r.value]));
  let html = base ? "<tr><th>figure</th><th>baseline</th><th>current</th><th>change</th><th>unit</th></tr>"
    : "<tr><th>figure</th><th>value</th><th>unit</th></tr>";
  for (const r of answer.views.datasheet) {
    html += `<tr data-key="${r.key}"><td>${r.label}</td>`;
    if (base) {
      const b = base[r.key];
      const delta = b === null || r.value === null ? null : r.value - b;
      const cls = delta === null || delta === 0 ? "" : delta > 0 ? "up" : "down";
      html += `<td class="baseline">${fmt(b, r.unit)}</td><td class="current">${fmt(r.value, r.unit)}</td>` +
        `<td class="change ${cls}" data-value="${delta === null ? "" : delta}">${delta === null ? "–" : (delta > 0 ? "+" : "") + fmt(delta, r.unit)}</td>`;
    } else {
      html += `<td class="current">${fmt(r.value, r.unit)}</td>`;
    }
    html += `<td>${r.unit === "-" ? "" : r.unit}</td></tr>`;
  }
  t.innerHTML = html;
  for (const r of answer.views.datasheet) t.querySelector(`tr[data-key="${r.key}"] td.current`).dataset.value = r.value ?? "";
}

function drawCurves(answer) {
  const svg = $("curves");
  svg.replaceChildren();
  const c = answer.views.curves;
  const vb = svg.viewBox.baseVal;
  const L = 46, R = 10, T = 12, B = 30;
  const xs = c.distance_mm, all = [...c.dz_um, ...c.dx_um];
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y1 = Math.max(...all) * 1.08;
  const X = (x) => L + (vb.width - L - R) * (x - x0) / Math.max(x1 - x0, 1e-9);
  const Y = (y) => vb.height - B - (vb.height - T - B) * y / y1;
  el("line", { x1: L, y1: vb.height - B, x2: vb.width - R, y2: vb.height - B, class: "axis" }, svg);
  el("line", { x1: L, y1: T, x2: L, y2: vb.height - B, class: "axis" }, svg);
  for (let i = 0; i <= 4; i++) {
    const y = (y1 * i) / 4, x = x0 + ((x1 - x0) * i) / 4;
    text(svg, 4, Y(y) + 4, y.toFixed(0));
    text(svg, X(x) - 12, vb.height - B + 14, x.toFixed(0));
  }
  text(svg, vb.width / 2 - 40, vb.height - 4, "D [mm]");
  for (const [key, color, name] of [["dz_um", "#1f77b4", "ΔZ"], ["dx_um", "#ff7f0e", "ΔX"]]) {
    const pts = xs.map((x, i) => `${X(x).toFixed(1)},${Y(c[key][i]).toFixed(1)}`).join(" ");
    el("polyline", { points: pts, fill: "none", stroke: color, "stroke-width": 1.6 }, svg);
    const n = xs.length - 1;
    text(svg, X(xs[n]) - 24, Y(c[key][n]) - 6, name, { fill: color });
  }
  // the sheet's margin inside the wedge of focus [mm], on its own scale (right), zero marked
  const m = c.margin_mm.map((v) => (v === null ? NaN : v)).filter(Number.isFinite);
  if (m.length) {
    const lo = Math.min(0, ...m), hi = Math.max(0, ...m), span = Math.max(hi - lo, 1e-9);
    const M = (v) => vb.height - B - (vb.height - T - B) * (0.05 + 0.9 * (v - lo) / span);
    el("line", { x1: L, y1: M(0), x2: vb.width - R, y2: M(0), stroke: "#2ca02c", "stroke-dasharray": "2 3" }, svg);
    const pts = xs.map((x, i) => (c.margin_mm[i] === null ? null : `${X(x).toFixed(1)},${M(c.margin_mm[i]).toFixed(1)}`))
      .filter(Boolean).join(" ");
    el("polyline", { points: pts, fill: "none", stroke: "#2ca02c", "stroke-width": 1.2 }, svg);
    text(svg, X(xs[0]) + 4, M(c.margin_mm[0] ?? 0) - 5,
      `sheet inside the wedge of focus by ${Math.min(...m).toFixed(2)} … ${Math.max(...m).toFixed(2)} mm`, { fill: "#2ca02c" });
  }
}

// The sheet's margin inside the wedge of focus over the whole sensor: green inside, red outside
// (a canvas: 561 cells redrawn on every input event cost nothing there).
function drawFocusMap(answer) {
  const canvas = $("focusmap"), ctx = canvas.getContext("2d");
  const fm = answer.views.focus_map, k = canvas.width / 520;
  ctx.setTransform(k, 0, 0, k, 0, 0);
  ctx.clearRect(0, 0, 520, canvas.height / k);
  const rows = fm.margin_mm.length, cols = fm.margin_mm[0].length;
  const all = fm.margin_mm.flat().filter((v) => v !== null);
  const lo = Math.min(0, ...all), hi = Math.max(0, ...all);
  const L = 46, T = 18, W = 520 - L - 10, H = canvas.height / k - T - 8;
  for (let i = 0; i < rows; i++) {
    for (let j = 0; j < cols; j++) {
      const v = fm.margin_mm[i][j];
      let fill = "#000";
      if (v !== null) {
        const a = v >= 0 ? 0.15 + 0.85 * v / Math.max(hi, 1e-9) : 0.15 + 0.85 * v / Math.min(lo, -1e-9);
        fill = v >= 0 ? `rgba(44,160,44,${a.toFixed(3)})` : `rgba(214,39,40,${a.toFixed(3)})`;
      }
      ctx.fillStyle = fill;
      ctx.fillRect(L + (W * j) / cols, T + (H * i) / rows, W / cols + 0.6, H / rows + 0.6);
    }
  }
  ctx.fillStyle = "#333";
  ctx.font = "11px system-ui, sans-serif";
  ctx.fillText("row 0", 4, T + 10);
  ctx.fillText(`row ${Math.round(fm.rows_px[rows - 1] - 0.5)}`, 4, T + H);
  ctx.fillText(`focus margin over the sensor (columns →): ${Math.min(...all).toFixed(2)} … ${Math.max(...all).toFixed(2)} mm` +
    (Math.min(...all) < 0 ? " — red: the sheet outside the wedge" : ""), L, 12);
}

function drawPlans(answer) {
  const d = answer.design, c = d.calibration_plan, r = d.rotary_plan;
  const items = [];
  const last = c.start_mm + (c.steps - 1) * c.step_mm;
  items.push(`calibration: plate ${c.plate_height_mm} mm on a table at ${c.table_z_mm} mm; ${c.steps} frames, ` +
    `s = ${c.start_mm} … ${last.toPrecision(6)} mm in steps of ${c.step_mm} mm; both edges in ${c.both_edges_frames} of ${c.steps}` +
    (c.note ? ` — ${c.note}` : ""));
  items.push(r.in_view ? `rotary: axis at s = ${r.axis_mm} mm (D = ${r.axis_distance_mm.toFixed(1)} mm), in view at every angle: ` +
    `a cylinder of radius ${r.part_radius_mm.toFixed(1)} mm and height ${r.part_height_mm.toFixed(1)} mm`
    : `rotary: axis at s = ${r.axis_mm} mm: OUT OF VIEW`);
  const ul = $("plans");
  ul.innerHTML = "";
  for (const s of items) ul.insertAdjacentHTML("beforeend", `<li></li>`), ul.lastChild.textContent = s;
  for (const w of answer.warnings) {
    const li = document.createElement("li");
    li.className = "warning";
    li.textContent = `warning: ${w.message}`;
    ul.append(li);
  }
}

function exports(q) {
  const s = q ? `?${q}` : "";
  $("export-toml").href = `/api/rig.toml${s}`;
  $("export-md").href = `/api/datasheet.md${s}`;
  $("export-csv").href = `/api/datasheet.csv${s}`;
  $("export-study").href = `/api/study.toml${s}`;
  $("export-link").href = `${location.origin}${location.pathname}${s}`;
}

// ------------------------------------------------------------------ occlusion on a part
// Asked for when the design, the part or the table angle changes (one request on its way, the newest
// state asked for when it returns); over one turn only on the button (≈ 1.5 s).

function occlusionRequest(turn = false) {
  previewRequest();
  const o = state.occ;
  if (!o.on) return;
  o.want += 1;
  if (turn) o.wantTurn = true;
  if (!o.inflight) occlusionSend();
}

async function occlusionSend() {
  const o = state.occ;
  o.inflight = true;
  const want = o.want, turn = !!o.wantTurn;
  o.wantTurn = false;
  const q = state.lastQuery || query();
  const extra = `part=${encodeURIComponent(o.part)}&angle_deg=${o.angle}${turn ? "&turn=1" : ""}`;
  let body = null, ok = false;
  try {
    const resp = await fetch(`/api/occlusion?${q}${q ? "&" : ""}${extra}`);
    body = await resp.json();
    ok = resp.ok;
  } catch (err) {
    body = { error: `the studio does not answer (${err.message})` };
  }
  o.inflight = false;
  o.done = want;
  if (ok) {
    o.last = body;
    if (body.turn) o.turn = { part: body.part, fractions: body.turn, query: q };
    if (state.last) drawField(state.last);
    occlusionText(body);
  } else {
    o.last = null;
    $("occ-result").textContent = body.error;
  }
  document.body.dataset.occ = String(o.done);
  if (o.want > want || o.wantTurn) occlusionSend();
}

// The preview: the same lane discipline, one render on its way; a 409 says a newer one overtook it.
function previewRequest() {
  const p = state.preview;
  if (!p.on) return;
  p.want += 1;
  if (!p.inflight) previewSend();
}

async function previewSend() {
  const p = state.preview, o = state.occ;
  p.inflight = true;
  const want = p.want, q = state.lastQuery || query();
  const extra = `part=${encodeURIComponent(o.part)}&angle_deg=${o.angle}`;
  $("preview-cap").textContent = "rendering …";
  try {
    const resp = await fetch(`/api/preview.png?${q}${q ? "&" : ""}${extra}`);
    if (resp.ok) {
      const blob = await resp.blob();
      if (p.url) URL.revokeObjectURL(p.url);
      p.url = URL.createObjectURL(blob);
      $("preview-img").src = p.url;
      $("preview").hidden = false;
      $("preview-cap").textContent = `${o.part} at ${o.angle}°, the twin's frame on a 4 × 4 binned sensor ` +
        `(scaled to its brightest pixel), rendered in ${Number(resp.headers.get("X-Render-Seconds")).toFixed(2)} s`;
    } else if (resp.status !== 409) {
      $("preview-cap").textContent = (await resp.json()).error;
    }
  } catch (err) {
    $("preview-cap").textContent = `the studio does not answer (${err.message})`;
  }
  p.inflight = false;
  p.done = want;
  document.body.dataset.preview = String(p.done);
  if (p.want > want) previewSend();
}

function drawOcclusionPoints(occ) {
  const svg = $("field"), f = state.fieldFrame;
  if (!f) return;
  const g = el("g", { id: "occ-layer" }, svg);
  for (const [d0, h0, d1, h1, k] of occ.segments) {
    const name = occ.classes[k];
    const [x1, y1] = f([d0, h0]), [x2, y2] = f([d1, h1]);
    el("line", { x1, y1, x2, y2, stroke: OCC_COLOURS[name], "stroke-width": name === "unreached" ? 1 : 2.5,
      "stroke-linecap": "round" }, g);
  }
}

function occlusionText(occ) {
  const pct = (v) => `${(100 * v).toFixed(1)} %`;
  const line = (fr) => occ.classes.map((c) => `<span class="c" style="background:${OCC_COLOURS[c]}"></span>` +
    `${OCC_NAMES[c]} <b data-class="${c}" data-value="${fr[c]}">${pct(fr[c])}</b>`).join("");
  let html = `at ${occ.angle_deg}°: ${line(occ.fractions)}`;
  const t = state.occ.turn;
  if (t && t.part === occ.part && t.query === state.lastQuery) html += `<br>over one turn: ${line(t.fractions)}`;
  $("occ-result").innerHTML = html;
}

async function upload(file) {
  const out = $("occ-result");
  if (file.size > state.maxUpload) {
    out.textContent = `${file.name} is ${(file.size / 2 ** 20).toFixed(1)} MB: at most ${state.maxUpload / 2 ** 20} MB`;
    return;
  }
  out.textContent = `uploading ${file.name} …`;
  let resp, body;
  try {
    resp = await fetch(`/api/mesh?name=${encodeURIComponent(file.name)}`, { method: "POST", body: file });
    body = await resp.json();
  } catch (err) {
    out.textContent = `the upload failed (${err.message})`;
    return;
  }
  if (!resp.ok) { out.textContent = body.error; return; }
  const sel = $("occ-part");
  sel.insertAdjacentHTML("beforeend", `<option></option>`);
  sel.lastChild.value = body.part;
  sel.lastChild.textContent = `${body.name} (uploaded, ${body.faces} triangles)`;
  sel.value = body.part;
  state.occ.part = body.part;
  state.occ.turn = null;
  out.textContent = body.warnings.length ? `warning: ${body.warnings.join("; ")}` : "";
  if (!state.occ.on) { $("occ-on").checked = true; state.occ.on = true; }
  occlusionRequest();
}

function occlusionControls(parts) {
  const o = state.occ, sel = $("occ-part");
  for (const p of parts) sel.insertAdjacentHTML("beforeend", `<option value="${p}">${p}</option>`);
  sel.value = parts.includes(o.part) ? o.part : parts[0];
  o.part = sel.value;
  $("occ-on").addEventListener("change", () => {
    o.on = $("occ-on").checked;
    if (o.on) occlusionRequest();
    else { o.last = null; $("occ-result").textContent = ""; if (state.last) drawField(state.last); }
  });
  sel.addEventListener("change", () => { o.part = sel.value; o.turn = null; occlusionRequest(); });
  $("occ-angle").addEventListener("input", () => {
    o.angle = Number($("occ-angle").value);
    $("occ-angle-v").textContent = `${o.angle}°`;
    occlusionRequest();
  });
  $("occ-file").addEventListener("change", () => { if ($("occ-file").files.length) upload($("occ-file").files[0]); });
  $("prev-on").addEventListener("change", () => {
    state.preview.on = $("prev-on").checked;
    $("preview").hidden = !state.preview.on;
    previewRequest();
  });
  $("occ-turn").addEventListener("click", () => {
    if (!o.on) { $("occ-on").checked = true; o.on = true; }
    occlusionRequest(true);
  });
}

// ------------------------------------------------------------------ solve for a range

async function solve(ev) {
  ev.preventDefault();
  const ul = $("proposals");
  const near = encodeURIComponent($("solve-near").value.trim()), far = encodeURIComponent($("solve-far").value.trim());
  const q = query();
  const resp = await fetch(`/api/solve?${q}${q ? "&" : ""}near_mm=${near}&far_mm=${far}`);
  const body = await resp.json();
  ul.replaceChildren();
  if (!resp.ok) {
    ul.insertAdjacentHTML("beforeend", `<li class="refused"></li>`);
    ul.lastChild.textContent = body.error;
    return;
  }
  for (const p of body.proposals) {
    const li = document.createElement("li");
    if (p.error) {
      li.className = "refused";
      li.textContent = `${p.label}: ${p.error}`;
    } else {
      const d = p.design;
      const keys = Object.entries(p.keys).map(([k, v]) => `${k} = ${Number(v).toPrecision(6)}`).join(", ");
      li.textContent = `${p.label}: ${keys}; β = ${d.tilt_deg.toFixed(3)}°, ΔZ centre ${(d.distance_resolution_center_mm * 1e3).toFixed(1)} µm` +
        (d.warnings.length ? ` (${d.warnings.length} warning${d.warnings.length > 1 ? "s" : ""})` : "");
      const b = document.createElement("button");
      b.type = "button";
      b.textContent = "apply";
      b.addEventListener("click", () => {
        for (const [k, v] of Object.entries(p.keys)) {
          state.set.set(k, String(v));
          const key = state.byName.get(k);
          if (key && key.el.slider) key.el.spanSet = false;
        }
        state.lastKey = null;
        request();
      });
      li.append(b);
    }
    ul.append(li);
  }
}

async function focusSolve() {
  const out = $("focus-result");
  const q = state.lastQuery || query();
  const resp = await fetch(`/api/focus?${q}`);
  const body = await resp.json();
  out.replaceChildren();
  if (!resp.ok) { out.textContent = body.error; return; }
  if (body.f_number === null) {
    out.textContent = `no f-number up to 256 holds the sheet's ±${(body.needed_mm * 1e3).toFixed(0)} µm ` +
      `(margin ${body.margin_mm === null ? "–" : body.margin_mm.toFixed(3)} mm at f/256)`;
    return;
  }
  const n = Math.ceil(body.f_number * 100 - 1e-9) / 100;      // rounded up: still sharp
  out.textContent = `f/${n}: the sheet's ±${(body.needed_mm * 1e3).toFixed(0)} µm inside the wedge over the whole range `;
  out.dataset.value = String(body.f_number);
  const b = document.createElement("button");
  b.type = "button";
  b.textContent = "apply";
  b.addEventListener("click", () => { state.set.set("lens.f_number", String(n)); state.lastKey = "lens.f_number"; request(); });
  out.append(b);
}

// ------------------------------------------------------------------ baseline, preset, start

function pin() {
  if (!state.last) return;
  state.baseline = { answer: state.last, query: state.lastQuery };
  $("unpin").hidden = false;
  drawAll();
}

function unpin() {
  state.baseline = null;
  $("unpin").hidden = true;
  drawAll();
}

function drawAll() {
  if (!state.last) return;
  drawMeridian(state.last);
  drawField(state.last);
  drawDatasheet(state.last);
}

async function start() {
  const resp = await fetch("/api/keys");
  const info = await resp.json();
  state.keys = info.keys;
  for (const k of state.keys) state.byName.set(k.name, k);
  readLocation();
  const sel = $("preset");
  const options = info.base_is_preset ? [] : [["", info.base]];
  for (const p of info.presets) options.push([p, `preset ${p}`]);
  for (const [value, label] of options) sel.insertAdjacentHTML("beforeend", `<option value="${value}">${label}</option>`);
  sel.value = state.preset || (info.base_is_preset ? info.base.replace(/^preset '(.*)'$/, "$1") : "");
  if (info.base_is_preset && !state.preset) state.preset = sel.value;
  sel.addEventListener("change", () => {
    state.preset = sel.value || null;
    state.set.clear();
    for (const k of state.keys) if (k.el.slider) k.el.spanSet = false;
    request();
  });
  $("subpixel").value = state.subpixel;
  $("subpixel").addEventListener("input", (ev) => { state.subpixel = $("subpixel").value.trim() || "1"; state.lastKey = null; request(ev.timeStamp); });
  $("pin").addEventListener("click", pin);
  $("solve").addEventListener("submit", solve);
  $("focus").addEventListener("click", focusSolve);
  state.maxUpload = info.max_upload_bytes;
  occlusionControls(info.parts);
  $("unpin").addEventListener("click", unpin);
  $("export-link").addEventListener("click", (ev) => {
    ev.preventDefault();
    if (navigator.clipboard) navigator.clipboard.writeText($("export-link").href).catch(() => {});
    $("status").textContent = "link copied (it is also this page's address)";
  });
  buildControls();
  await request();
}

start();
