/* The interactive 3D view of mocapflow's pages (presentation/viewer.py writes it into the report and the compare
   page, with the page's data and options). Canvas 2D, no library, nothing fetched.

   DATA.sequences: per sequence (a take) its id (and label), fps, frames (and times, s, where its frames are not
   frame / fps), parents (the skeleton's), its tracks (per frame a list of [x, y, z] mm or null, under any key) and
   its views: one canvas each, drawing layers of tracks (kind "markers": a colour per marker, far first; "points":
   dots of one colour; "skeleton": the bones by parents), an optional caption (a value per frame) and the body
   attribute its painted pixels go to; its legend: entries beside the markers' names.
   OPTIONS: what a sequence is called (the body's data-<what> attribute), the canvas size, the span across the
   canvas's height (mm), the tracks the views turn about, the palette (markers; views overlaid), whether the views
   may be overlaid on one canvas (each view's "tint" layers in its palette colour, "overlay": false layers left
   out, a track's layer drawn once; the body then carries data-overlay and data-painted-overlay).
   Drag to turn, the wheel to zoom, space or the button to play, the slider or the arrow keys to step. Once frame 0
   is drawn the body carries data-<what>, data-frames and per view its painted attribute (canvas pixels drawn over
   the background), so a headless browser can tell that it ran. */
"use strict";

// A marker's colour among n: the categorical palette while it has a colour for each, else hues a golden angle
// apart (neighbouring markers far apart on the wheel) at three lightnesses: distinct for any count.
function markerColour(m, n, palette) {
  if (n <= palette.length) return palette[m];
  var hue = (m * 137.50776405) % 360, light = [58, 42, 74][m % 3];
  return "hsl(" + hue.toFixed(2) + ",70%," + light + "%)";
}

var BG = [30, 30, 30], GRID = "#3c3c3c";

// The view of a page: mocapViewer(DATA, OPTIONS) finds its controls (mf-*), binds them and draws sequence 0.
function mocapViewer(DATA, OPTIONS) {
  var byId = function (id) { return document.getElementById(id); };
  var v = {data: DATA, options: OPTIONS, canvases: [], drag: null,
           state: {seq: 0, frame: 0, az: -0.9, el: 0.3, zoom: 1, playing: false, last: 0, overlay: false},
           select: byId("mf-select"), slider: byId("mf-frame"), label: byId("mf-label"), legend: byId("mf-legend"),
           views: byId("mf-views"), play: byId("mf-play"), overlay: byId("mf-overlay")};
  bindControls(v);
  if (DATA.sequences.length) choose(v, 0);
  return v;
}

function centre(seq, keys) {  // mean of the positions of the tracks ``keys`` (mm): every view turns about it
  var s = [0, 0, 0], n = 0;
  keys.forEach(function (key) {
    (seq[key] || []).forEach(function (f) { f.forEach(function (p) {
      if (p) { s[0] += p[0]; s[1] += p[1]; s[2] += p[2]; n += 1; } }); });
  });
  return n ? [s[0] / n, s[1] / n, s[2] / n] : [0, 0, 0];
}

function project(v, cv, p, c) {  // world mm (Z up) -> canvas px and depth, orbiting about c
  var st = v.state, x = p[0] - c[0], y = p[1] - c[1], z = p[2] - c[2];
  var ca = Math.cos(st.az), sa = Math.sin(st.az), ce = Math.cos(st.el), se = Math.sin(st.el);
  var xr = ca * x - sa * y, yr = sa * x + ca * y;
  var s = cv.height / v.options.span_mm * st.zoom;  // span_mm across the canvas's height
  return [cv.width / 2 + xr * s, cv.height / 2 - (ce * z - se * yr) * s, ce * yr + se * z];
}

function line(ctx, a, b, colour, width, dash) {
  ctx.strokeStyle = colour; ctx.lineWidth = width; ctx.setLineDash(dash || []);
  ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke(); ctx.setLineDash([]);
}

function floor(v, cv, c) {  // the background and a 4 m floor grid at z = 0, lines every 0.5 m
  var ctx = cv.getContext("2d");
  ctx.fillStyle = "rgb(" + BG.join(",") + ")"; ctx.fillRect(0, 0, cv.width, cv.height);
  for (var k = -4; k <= 4; k++) {
    var a = k * 500;
    line(ctx, project(v, cv, [c[0] + a, c[1] - 2000, 0], c), project(v, cv, [c[0] + a, c[1] + 2000, 0], c), GRID, 1);
    line(ctx, project(v, cv, [c[0] - 2000, c[1] + a, 0], c), project(v, cv, [c[0] + 2000, c[1] + a, 0], c), GRID, 1);
  }
}

function layer(v, cv, seq, spec, colour, f) {  // one layer of frame f; returns the points drawn
  var xyz = seq[spec.track] ? seq[spec.track][f] : null, ctx = cv.getContext("2d"), c = seq.centre;
  if (!xyz) return 0;
  if (spec.kind === "skeleton") {
    seq.parents.forEach(function (p, j) {
      if (p >= 0 && xyz[j] && xyz[p]) line(ctx, project(v, cv, xyz[j], c), project(v, cv, xyz[p], c), colour,
                                           spec.width, spec.dash);
    });
    return 0;
  }
  var pts = [];
  xyz.forEach(function (p, m) { if (p) { var q = project(v, cv, p, c); pts.push([q[2], q[0], q[1], m]); } });
  if (spec.kind === "markers") pts.sort(function (a, b) { return b[0] - a[0]; });  // far first
  pts.forEach(function (q) {
    ctx.fillStyle = spec.kind === "markers" ? markerColour(q[3], xyz.length, v.options.palette) : colour;
    ctx.beginPath(); ctx.arc(q[1], q[2], spec.radius, 0, 2 * Math.PI); ctx.fill();
  });
  return pts.length;
}

function caption(seq, view, f) {  // "name: value unit", or "" for a view without a caption
  if (!view.caption) return "";
  var value = seq[view.caption.values][f];
  return view.name + ": " + (value === null ? view.caption.missing : value.toFixed(1) + " " + view.caption.unit);
}

function draw(v) {  // the frame on every canvas, its captions and the label
  var st = v.state, seq = v.data.sequences[st.seq], f = st.frame, t = seq.times ? seq.times[f] : f / seq.fps;
  var shown = null, drawn = {}, texts = [], palette = v.options.palette;
  v.canvases.forEach(function (cv) { floor(v, cv, seq.centre); });
  seq.views.forEach(function (view, k) {
    var cv = v.canvases[st.overlay ? 0 : k];
    view.layers.forEach(function (spec) {
      var key = spec.kind + " " + spec.track;
      if (st.overlay && (spec.overlay === false || drawn[key])) return;
      drawn[key] = true;
      var n = layer(v, cv, seq, spec, st.overlay && spec.tint ? palette[k % palette.length] : spec.colour, f);
      if (spec.kind === "markers" && k === 0) shown = [n, seq[spec.names].length];
    });
    texts.push(caption(seq, view, f));
  });
  v.canvases.forEach(function (cv, k) {
    var text = st.overlay ? texts.filter(Boolean).join(", ") : texts[k];
    cv.parentNode.querySelector("figcaption").textContent = text ? text + " at " + t.toFixed(2) + " s" : "";
  });
  v.label.textContent = "frame " + f + " / " + (seq.frames - 1) + ", " + t.toFixed(2) + " s" +
    (shown ? ", " + shown[0] + " of " + shown[1] + " markers" : "");
  v.slider.value = f;
}

function painted(cv) {  // canvas pixels that differ from the background (every 4th pixel, times 4)
  var px = cv.getContext("2d").getImageData(0, 0, cv.width, cv.height).data, n = 0;
  for (var i = 0; i < px.length; i += 16) {
    if (px[i] !== BG[0] || px[i + 1] !== BG[1] || px[i + 2] !== BG[2]) n += 4;
  }
  return n;
}

function entry(legend, colour, round, text) {
  var li = document.createElement("li"), swatch = document.createElement("span");
  swatch.style.background = colour;
  if (!round) swatch.style.borderRadius = "0";
  li.appendChild(swatch); li.appendChild(document.createTextNode(text)); legend.appendChild(li);
}

function showLegend(v, seq) {  // the views' colours when overlaid, the markers by name, the sequence's entries
  var palette = v.options.palette, overlaid = v.state.overlay;
  v.legend.innerHTML = "";
  if (overlaid) seq.views.forEach(function (view, k) {
    entry(v.legend, palette[k % palette.length], false, view.name);
  });
  seq.views[0].layers.forEach(function (spec) {
    if (spec.kind !== "markers") return;
    var names = seq[spec.names];
    names.forEach(function (name, m) { entry(v.legend, markerColour(m, names.length, palette), true, name); });
  });
  (seq.legend || []).forEach(function (item) {
    if (!(overlaid && item.tint)) entry(v.legend, item.colour, item.shape === "dot", item.label);
  });
}

function layout(v) {  // one canvas per view, or one for them all overlaid
  var seq = v.data.sequences[v.state.seq], n = v.state.overlay ? 1 : seq.views.length;
  v.views.innerHTML = ""; v.canvases = [];
  for (var k = 0; k < n; k++) {
    var fig = document.createElement("figure"), cv = document.createElement("canvas");
    cv.width = v.options.width; cv.height = v.options.height;
    fig.appendChild(cv); fig.appendChild(document.createElement("figcaption"));
    v.views.appendChild(fig); v.canvases.push(cv);
    cv.addEventListener("mousedown", function (e) { v.drag = [e.clientX, e.clientY]; });
    cv.addEventListener("wheel", function (e) {
      v.state.zoom = Math.max(0.2, Math.min(8, v.state.zoom * (e.deltaY < 0 ? 1.1 : 1 / 1.1)));
      draw(v); e.preventDefault();
    }, {passive: false});
  }
  showLegend(v, seq);
}

function choose(v, index) {  // show sequence ``index`` from its frame 0; mark the body once drawn
  v.state.seq = index; v.state.frame = 0;
  var seq = v.data.sequences[index];
  seq.centre = seq.centre || centre(seq, v.options.centre);
  v.slider.max = seq.frames - 1;
  layout(v);
  draw(v);
  document.body.setAttribute("data-" + v.options.what, seq.id);
  document.body.setAttribute("data-frames", String(seq.frames));
  if (!v.state.overlay) seq.views.forEach(function (view, k) {
    document.body.setAttribute(view.painted, String(painted(v.canvases[k])));
  });
}

function toggleOverlay(v) {
  v.state.overlay = !v.state.overlay; v.overlay.textContent = v.state.overlay ? "side by side" : "overlay";
  layout(v); draw(v);
  document.body.setAttribute("data-overlay", String(v.state.overlay));
  if (v.state.overlay) document.body.setAttribute("data-painted-overlay", String(painted(v.canvases[0])));
}

function togglePlay(v) {  // play at the sequence's rate, looping
  var st = v.state;
  st.playing = !st.playing; v.play.textContent = st.playing ? "pause" : "play";
  if (!st.playing) return;
  requestAnimationFrame(function tick(now) {
    if (!st.playing) return;
    var seq = v.data.sequences[st.seq];
    if (now - st.last >= 1000 / seq.fps) { st.last = now; st.frame = (st.frame + 1) % seq.frames; draw(v); }
    requestAnimationFrame(tick);
  });
}

function bindControls(v) {  // the chooser, slider, buttons, keys, drag to turn
  v.data.sequences.forEach(function (seq, i) {
    var o = document.createElement("option");
    o.value = i; o.textContent = seq.label && seq.label !== seq.id ? seq.id + " (" + seq.label + ")" : seq.id;
    v.select.appendChild(o);
  });
  v.select.addEventListener("change", function () { choose(v, Number(v.select.value)); });
  v.slider.addEventListener("input", function () { v.state.frame = Number(v.slider.value); draw(v); });
  v.play.addEventListener("click", function () { togglePlay(v); });
  if (v.overlay) v.overlay.addEventListener("click", function () { toggleOverlay(v); });
  document.addEventListener("keydown", function (e) {
    var st = v.state, last = v.data.sequences[st.seq].frames - 1;
    if (e.key === " ") { togglePlay(v); e.preventDefault(); }
    if (e.key === "ArrowRight") { st.frame = Math.min(st.frame + 1, last); draw(v); }
    if (e.key === "ArrowLeft") { st.frame = Math.max(st.frame - 1, 0); draw(v); }
  });
  window.addEventListener("mouseup", function () { v.drag = null; });
  window.addEventListener("mousemove", function (e) {
    if (!v.drag) return;
    v.state.az += (e.clientX - v.drag[0]) * 0.01;
    v.state.el = Math.max(-1.5, Math.min(1.5, v.state.el + (e.clientY - v.drag[1]) * 0.01));
    v.drag = [e.clientX, e.clientY]; draw(v);
  });
}
