"""The report's interactive 3D view: one self-contained HTML page (inline script, canvas 2D, the data inline).

A page and not a Rerun recording: it opens in any browser, offline, with nothing to install, travels as one
file beside the report, and its test runs in a headless browser; rerun-sdk would add a large dependency and a
viewer program to every machine that looks at a take.

The data (``/*DATA*/null``, replaced by ``report.viewer_html``) holds per sequence its markers and joints per
frame in millimetres (``null`` where missing), the skeleton's parents and the ground-truth joints where known.
Drag to turn the view, the wheel to zoom, space or the button to play, the slider or the arrow keys to step.
Once frame 0 is drawn the page marks its body with ``data-frames`` (the sequence's frames) and ``data-painted``
(canvas pixels drawn over the background), so a headless browser can tell that it ran.
"""

# A marker's colour among ``n``: the categorical palette while it has a colour for each, else hues a golden angle
# apart (neighbouring markers far apart on the wheel) at three lightnesses: distinct for any count.
MARKER_COLOUR_JS = r"""
  function markerColour(m, n, palette) {
    if (n <= palette.length) return palette[m];
    var hue = (m * 137.50776405) % 360, light = [58, 42, 74][m % 3];
    return "hsl(" + hue.toFixed(2) + ",70%," + light + "%)";
  }
"""

VIEWER = r"""<!doctype html><html><head><meta charset="utf-8"><title>3D view</title><style>
#mf-viewer{display:flex;gap:1em;align-items:flex-start;flex-wrap:wrap}
#mf-canvas{background:#1e1e1e;border-radius:4px;cursor:grab}
#mf-controls{margin:.5em 0}#mf-controls>*{margin-right:.6em;vertical-align:middle}
#mf-legend{list-style:none;padding:0;margin:0;font-size:12px;columns:2}
#mf-legend li{white-space:nowrap}#mf-legend span{display:inline-block;width:10px;height:10px;border-radius:5px;
margin-right:4px}</style></head><body>
<div id="mf-controls"><label>sequence <select id="mf-seq"></select></label><button id="mf-play">play</button>
<input id="mf-frame" type="range" min="0" value="0" style="width:320px"><span id="mf-label"></span></div>
<div id="mf-viewer"><canvas id="mf-canvas" width="720" height="540"></canvas><ul id="mf-legend"></ul></div>
<script>
(function () {
  "use strict";
  var DATA = /*DATA*/null;
  var BG = [30, 30, 30], SOLVED = "#ffa040", TRUTH = "#f0f0f0";
/*MARKER_COLOUR*/
  var canvas = document.getElementById("mf-canvas"), ctx = canvas.getContext("2d");
  var select = document.getElementById("mf-seq"), slider = document.getElementById("mf-frame");
  var label = document.getElementById("mf-label"), legend = document.getElementById("mf-legend");
  var play = document.getElementById("mf-play");
  var state = {seq: 0, frame: 0, az: -0.9, el: 0.3, zoom: 1, playing: false, last: 0};

  function centre(seq) {  // mean of every marker and joint position (mm): the view turns about it
    var s = [0, 0, 0], n = 0;
    [seq.marker_xyz, seq.joint_xyz].forEach(function (frames) {
      (frames || []).forEach(function (f) { f.forEach(function (p) {
        if (p) { s[0] += p[0]; s[1] += p[1]; s[2] += p[2]; n += 1; } }); });
    });
    return n ? [s[0] / n, s[1] / n, s[2] / n] : [0, 0, 0];
  }

  function project(p, c) {  // world mm (Z up) -> canvas px and depth, orbiting about c
    var x = p[0] - c[0], y = p[1] - c[1], z = p[2] - c[2];
    var ca = Math.cos(state.az), sa = Math.sin(state.az), ce = Math.cos(state.el), se = Math.sin(state.el);
    var xr = ca * x - sa * y, yr = sa * x + ca * y;
    var s = canvas.height / 2600 * state.zoom;  // 2.6 m across the canvas's height
    return [canvas.width / 2 + xr * s, canvas.height / 2 - (ce * z - se * yr) * s, ce * yr + se * z];
  }

  function line(a, b, colour, width, dash) {
    ctx.strokeStyle = colour; ctx.lineWidth = width; ctx.setLineDash(dash || []);
    ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke(); ctx.setLineDash([]);
  }

  function skeleton(xyz, parents, c, colour, width, dash) {
    if (!xyz) return;
    parents.forEach(function (p, j) {
      if (p >= 0 && xyz[j] && xyz[p]) line(project(xyz[j], c), project(xyz[p], c), colour, width, dash);
    });
  }

  function draw() {
    var seq = DATA.sequences[state.seq], f = state.frame, c = seq.centre;
    ctx.fillStyle = "rgb(" + BG.join(",") + ")"; ctx.fillRect(0, 0, canvas.width, canvas.height);
    for (var k = -4; k <= 4; k++) {  // a 4 m floor grid at z = 0, lines every 0.5 m
      var a = k * 500;
      line(project([c[0] + a, c[1] - 2000, 0], c), project([c[0] + a, c[1] + 2000, 0], c), "#3c3c3c", 1);
      line(project([c[0] - 2000, c[1] + a, 0], c), project([c[0] + 2000, c[1] + a, 0], c), "#3c3c3c", 1);
    }
    if (seq.gt_joint_xyz) skeleton(seq.gt_joint_xyz[f], seq.parents, c, TRUTH, 1.5, [4, 3]);
    if (seq.joint_xyz) skeleton(seq.joint_xyz[f], seq.parents, c, SOLVED, 3);
    var pts = [];
    (seq.marker_xyz ? seq.marker_xyz[f] : []).forEach(function (p, m) {
      if (p) { var q = project(p, c); pts.push([q[2], q[0], q[1], m]); }
    });
    pts.sort(function (a, b) { return b[0] - a[0]; });  // far first
    pts.forEach(function (p) {
      ctx.fillStyle = markerColour(p[3], seq.markers.length, DATA.palette);
      ctx.beginPath(); ctx.arc(p[1], p[2], 4, 0, 2 * Math.PI); ctx.fill();
    });
    label.textContent = "frame " + f + " / " + (seq.frames - 1) + ", " + (f / seq.fps).toFixed(2) + " s, " +
      pts.length + " of " + seq.markers.length + " markers";
    slider.value = f;
  }

  function painted() {  // canvas pixels that differ from the background (every 4th pixel, times 4)
    var px = ctx.getImageData(0, 0, canvas.width, canvas.height).data, n = 0;
    for (var i = 0; i < px.length; i += 16) {
      if (px[i] !== BG[0] || px[i + 1] !== BG[1] || px[i + 2] !== BG[2]) n += 4;
    }
    return n;
  }

  function showLegend(seq) {
    var items = seq.markers.map(function (name, m) {
      return "<li><span style='background:" + markerColour(m, seq.markers.length, DATA.palette) + "'></span>" + name + "</li>";
    });
    if (seq.joint_xyz) items.push("<li><span style='background:" + SOLVED + ";border-radius:0'></span>solved skeleton</li>");
    if (seq.gt_joint_xyz) items.push("<li><span style='background:" + TRUTH + ";border-radius:0'></span>" +
                                     "ground-truth skeleton (dashed)</li>");
    legend.innerHTML = items.join("");
  }

  function choose(index) {
    state.seq = index; state.frame = 0;
    var seq = DATA.sequences[index];
    slider.max = seq.frames - 1;
    showLegend(seq);
    draw();
    document.body.setAttribute("data-sequence", seq.id);
    document.body.setAttribute("data-frames", String(seq.frames));
    document.body.setAttribute("data-painted", String(painted()));
  }

  function tick(now) {
    if (!state.playing) return;
    var seq = DATA.sequences[state.seq];
    if (now - state.last >= 1000 / seq.fps) {
      state.last = now; state.frame = (state.frame + 1) % seq.frames; draw();
    }
    requestAnimationFrame(tick);
  }

  function toggle() {
    state.playing = !state.playing; play.textContent = state.playing ? "pause" : "play";
    if (state.playing) requestAnimationFrame(tick);
  }

  DATA.sequences.forEach(function (seq, i) {
    seq.centre = centre(seq);
    var o = document.createElement("option");
    o.value = i; o.textContent = seq.label && seq.label !== seq.id ? seq.id + " (" + seq.label + ")" : seq.id;
    select.appendChild(o);
  });
  select.addEventListener("change", function () { choose(Number(select.value)); });
  slider.addEventListener("input", function () { state.frame = Number(slider.value); draw(); });
  play.addEventListener("click", toggle);
  document.addEventListener("keydown", function (e) {
    var seq = DATA.sequences[state.seq];
    if (e.key === " ") { toggle(); e.preventDefault(); }
    if (e.key === "ArrowRight") { state.frame = Math.min(state.frame + 1, seq.frames - 1); draw(); }
    if (e.key === "ArrowLeft") { state.frame = Math.max(state.frame - 1, 0); draw(); }
  });
  var drag = null;
  canvas.addEventListener("mousedown", function (e) { drag = [e.clientX, e.clientY]; });
  window.addEventListener("mouseup", function () { drag = null; });
  window.addEventListener("mousemove", function (e) {
    if (!drag) return;
    state.az += (e.clientX - drag[0]) * 0.01;
    state.el = Math.max(-1.5, Math.min(1.5, state.el + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY]; draw();
  });
  canvas.addEventListener("wheel", function (e) {
    state.zoom = Math.max(0.2, Math.min(8, state.zoom * (e.deltaY < 0 ? 1.1 : 1 / 1.1))); draw(); e.preventDefault();
  }, {passive: false});
  if (DATA.sequences.length) choose(0);
})();
</script></body></html>
""".replace("/*MARKER_COLOUR*/", MARKER_COLOUR_JS)
