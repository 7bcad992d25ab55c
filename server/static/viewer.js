// lumigraph web viewer: an orbit camera that streams views to /v1/stream and draws the frames
// it gets back (protocol: docs/protocol.md). Plain JS, no build step. The whole viewer state
// lives in the page's query string (docs/protocol.md, "Viewer links"), so a link opens the same view.
"use strict";

(() => {
  const $ = (id) => document.getElementById(id);
  const canvas = $("view");
  const ctx = canvas.getContext("2d");
  const statsEl = $("stats");
  const errorEl = $("error");
  const CODECS = ["image/png", "image/jpeg", "image/webp"];
  const QUALITY = ["interactive", "full"];

  const state = {
    ws: null,
    asset: null,
    maxPx: 4096,
    // Orbit camera around `target`: azimuth/elevation in radians, distance in world units.
    target: [0, 0, 0],
    azimuth: 0.6,
    elevation: 0.35,
    distance: 3,
    yfovDeg: 40,
    requestId: 0,
    sentAt: new Map(),
    frames: 0,
    frameTimes: [],
    last: null,
    dirty: false,
    drawing: Promise.resolve(),
    // The state the page's URL asked for, applied once the asset's hello arrives.
    fromUrl: null,
    // World-space light direction of an asset with light states; null: the baked light.
    light: null,
    // The last view message sent (tests compare it with the URL's camera).
    lastView: null,
    // Keys the stream settings carry that a later version may add (URL: light, time, focus).
    extra: {},
    // Reprojection (reproject.js): the camera changes, counted, so a drawn image can say which
    // camera it shows; the warper (null without WebGL2); a log of recent camera changes and
    // draws ({kind: "frame" | "warp", seq, t}) for the stats and for tests.
    cameraSeq: 0,
    seqOfRequest: new Map(),
    warper: null,
    warps: 0,
    changes: [],
    draws: [],
  };
  // Exposed for tests and for poking at from the console.
  window.lumigraphViewer = state;

  try {
    state.warper = window.LumigraphReproject ? window.LumigraphReproject.createWarper() : null;
  } catch (e) {
    console.warn("reprojection unavailable:", e);
  }
  state.warpCanvas = state.warper ? state.warper.canvas : null;
  const reprojectBox = $("reproject");
  if (!state.warper) { reprojectBox.checked = false; reprojectBox.disabled = true; }
  if (new URLSearchParams(location.search).get("reproject") === "0") reprojectBox.checked = false;
  const reprojecting = () => !!state.warper && reprojectBox.checked;

  function logEntry(list, entry) {
    list.push(entry);
    if (list.length > 512) list.shift();
  }

  // Problems with the URL's state: shown until dismissed (a click), never a blank page.
  function showNotice(lines) {
    const el = $("notice");
    el.textContent = lines.length ? "This link's state was adjusted:\n" + lines.join("\n") : "";
    el.style.display = lines.length ? "block" : "none";
  }

  function showError(message) {
    errorEl.textContent = message;
    errorEl.style.display = message ? "block" : "none";
    if (message) setTimeout(() => { if (errorEl.textContent === message) showError(""); }, 5000);
  }

  function viewSize() {
    const dpr = Math.min(window.devicePixelRatio || 1, 2);
    const w = Math.max(1, Math.min(state.maxPx, Math.round(canvas.clientWidth * dpr)));
    const h = Math.max(1, Math.min(state.maxPx, Math.round(canvas.clientHeight * dpr)));
    return [w, h];
  }

  function currentView() {
    const [w, h] = viewSize();
    const ce = Math.cos(state.elevation), se = Math.sin(state.elevation);
    const dir = [ce * Math.sin(state.azimuth), se, ce * Math.cos(state.azimuth)];
    const t = state.target;
    const eye = [t[0] + dir[0] * state.distance, t[1] + dir[1] * state.distance, t[2] + dir[2] * state.distance];
    return { eye, target: t.slice(), up: [0, 1, 0], yfov_deg: state.yfovDeg, width: w, height: h };
  }

  function send(message) {
    // A session the server closed for idleness (1008) reconnects at the next interaction; the
    // hello then sends the current settings and view.
    if (state.idleAsset) { const id = state.idleAsset; state.idleAsset = null; connect(id); return; }
    if (state.ws && state.ws.readyState === WebSocket.OPEN) state.ws.send(JSON.stringify(message));
  }

  // Views are sent at most once per animation frame; the server keeps only the latest anyway.
  function requestView(still) {
    state.cameraSeq += 1;
    logEntry(state.changes, { seq: state.cameraSeq, t: performance.now() });
    if (still) { sendView(true); drawWarped(); return; }
    if (state.dirty) return;
    state.dirty = true;
    requestAnimationFrame(() => { state.dirty = false; sendView(false); drawWarped(); });
  }

  // Draws the kept frames reprojected to the current camera, while the frame for it is on its
  // way; false when reprojection is off or there is nothing to warp.
  function drawWarped() {
    if (!reprojecting()) return false;
    if (!state.warper.draw(currentView())) return false;
    present(state.warper.canvas, true);
    state.warps += 1;
    logEntry(state.draws, { kind: "warp", seq: state.cameraSeq, t: performance.now() });
    return true;
  }

  // Puts an image on the visible canvas, over the background where it is transparent.
  function present(image, overBackground) {
    const [w, h2] = [canvas.clientWidth, canvas.clientHeight];
    if (canvas.width !== w || canvas.height !== h2) { canvas.width = w; canvas.height = h2; }
    ctx.imageSmoothingEnabled = true;
    if (overBackground) {
      ctx.fillStyle = $("background").value;
      ctx.fillRect(0, 0, canvas.width, canvas.height);
    } else {
      ctx.clearRect(0, 0, canvas.width, canvas.height);
    }
    ctx.drawImage(image, 0, 0, canvas.width, canvas.height);
  }

  function sendView(still) {
    state.requestId = (state.requestId + 1) >>> 0;
    state.sentAt.set(state.requestId, performance.now());
    if (state.sentAt.size > 256) state.sentAt.delete(state.sentAt.keys().next().value);
    state.seqOfRequest.set(state.requestId, state.cameraSeq);
    if (state.seqOfRequest.size > 256) state.seqOfRequest.delete(state.seqOfRequest.keys().next().value);
    state.lastView = currentView();
    send({ type: "view", id: state.requestId, view: state.lastView, still: !!still });
    if (state.light) drawLightPad();
    scheduleUrlUpdate();
  }

  function numberOrNull(el) {
    const v = parseFloat(el.value);
    return Number.isFinite(v) ? v : null;
  }

  function backgroundRgba() {
    const bg = $("background").value;
    const rgb = [1, 3, 5].map((i) => parseInt(bg.slice(i, i + 2), 16));
    return [rgb[0], rgb[1], rgb[2], 255];
  }

  const isTwoPlane = () => !!(state.asset && state.asset.kind === "two_plane");

  // The quality keys of the asset's kind: a two-plane light field takes uv_filter, focus,
  // aperture and refine (draws averaged at rest); a spherical one the marcher's knobs.
  function kindSettings() {
    if (isTwoPlane()) {
      return {
        uv_filter: $("uv_filter").value || null,
        focus: numberOrNull($("focus")) ?? 0,
        aperture: numberOrNull($("aperture")) ?? 0,
        refine: (numberOrNull($("aperture")) ?? 0) > 0 ? Math.max(1, Math.min(256, Math.round(numberOrNull($("accumulate")) ?? 8))) : null,
      };
    }
    return {
      lod: parseInt($("lod").value, 10) || null,
      method: $("method").value,
      step: numberOrNull($("step")),
      tolerance: numberOrNull($("tolerance")),
      auto_lod: numberOrNull($("auto_lod")),
    };
  }

  function sendSettings() {
    send({
      type: "settings",
      ...kindSettings(),
      still_codec: $("still_codec").value,
      interactive: $("interactive").checked,
      target_fps: numberOrNull($("target_fps")) || 20,
      rest_ms: Math.round(numberOrNull($("rest_ms")) ?? 250),
      background: backgroundRgba(),
      depth: reprojecting(),
    });
    scheduleUrlUpdate();
  }

  // --- layer opacity sliders (multi light fields) --------------------------------------------
  // One slider per layer of an asset with several; each change sends `layers` in a settings
  // message of its own and goes into the link as `layers=name:opacity,...`.
  function fromUrlLayers() {
    return state.fromUrl && state.fromUrl.settings.layers ? state.fromUrl.settings.layers : {};
  }

  function fillLayers(asset, initial) {
    const box = $("layers");
    box.innerHTML = "";
    const names = asset.layers || [];
    const defaults = asset.layer_opacities || [];
    box.hidden = names.length < 2;
    if (box.hidden) return;
    const title = document.createElement("div");
    title.textContent = "Layer opacity";
    box.appendChild(title);
    names.forEach((name, i) => {
      const label = document.createElement("label");
      label.className = "row";
      const input = document.createElement("input");
      input.type = "range";
      input.min = "0";
      input.max = "1";
      input.step = "0.01";
      input.dataset.layer = name;
      input.value = String(initial[name] ?? defaults[i] ?? 1);
      input.setAttribute("aria-label", `opacity of layer ${name}`);
      const text = document.createElement("span");
      text.textContent = ` ${name}`;
      label.append(input, text);
      box.appendChild(label);
      input.addEventListener("input", sendLayers);
    });
  }

  function layerOpacities() {
    const out = {};
    for (const input of $("layers").querySelectorAll("input[data-layer]")) {
      out[input.dataset.layer] = Number(input.value);
    }
    return out;
  }

  function sendLayers() {
    const layers = layerOpacities();
    state.extra.layers = Object.entries(layers).map(([k, v]) => `${k}:${v}`).join(",");
    send({ type: "settings", layers });
    sendView(true);
    scheduleUrlUpdate();
  }

  // --- deformation states -----------------------------------------------------------------------
  // A picker of the asset's deformation states (`bake --state NAME=MESH2`), shown when it has
  // any; a choice sends `state` in a settings message of its own and goes into the link as
  // `state=NAME` (left out for the base state).
  function fillStates(asset, initial) {
    const box = $("states");
    const sel = $("state");
    const names = asset.deformations || [];
    box.hidden = names.length === 0;
    sel.innerHTML = "";
    for (const name of ["base", ...names]) {
      const o = document.createElement("option");
      o.value = name;
      o.textContent = name;
      sel.appendChild(o);
    }
    sel.value = initial && names.includes(initial) ? initial : "base";
  }

  function sendState() {
    const name = $("state").value;
    if (name === "base") delete state.extra.state;
    else state.extra.state = name;
    send({ type: "settings", state: name === "base" ? null : name });
    sendView(true);
    scheduleUrlUpdate();
  }

  // --- animation playback ------------------------------------------------------------------------
  // Play / pause for an asset baked with --animation: `playing` in a settings message of its own
  // (the server advances the frames on its clock) and `playing=1` in the link. Paused, the frame
  // slider picks the frame (`time` in seconds to the server and in the link); pausing keeps the
  // frame on screen, and moving the slider while playing pauses.
  function fillPlayback(asset, playing, time) {
    $("playback").hidden = !asset.animation;
    state.playing = !!asset.animation && !!playing;
    $("play").textContent = state.playing ? "Pause" : "Play";
    const slider = $("frame");
    const a = asset.animation;
    slider.max = a ? String(Math.max(a.frames - 1, 0)) : "0";
    const frame = a && time != null ? Math.min(Math.floor(time * a.fps + 1e-6), a.frames - 1) : 0;
    showFrame(frame);
    if (!a || state.playing || !frame) delete state.extra.time;
  }

  function showFrame(frame) {
    $("frame").value = String(frame);
    $("frame_label").textContent = String(frame);
  }

  // The link's and the server's time of animation frame `frame`: its start, rounded to 0.1 ms
  // (the server shows the last frame at or before a time).
  function frameTime(frame) {
    return Number((frame / state.asset.animation.fps).toFixed(4));
  }

  function setFrame(frame, extra) {
    const time = frameTime(frame);
    if (frame > 0) state.extra.time = String(time); else delete state.extra.time;
    showFrame(frame);
    send({ type: "settings", ...extra, time: frame > 0 ? time : null });
  }

  // The button and the link follow `playing`; the server hears of it from the caller.
  function setPlaying(playing) {
    state.playing = playing;
    $("play").textContent = playing ? "Pause" : "Play";
    if (playing) state.extra.playing = "1"; else delete state.extra.playing;
  }

  function togglePlayback() {
    setPlaying(!state.playing);
    if (state.playing) {
      delete state.extra.time;
      send({ type: "settings", playing: true, time: null });
    } else {
      // Pausing keeps the frame last shown.
      const shown = state.last && state.last.animation ? state.last.animation.frame : Number($("frame").value);
      setFrame(shown, { playing: false });
    }
    sendView(true);
    scheduleUrlUpdate();
  }

  function scrubFrame() {
    const extra = state.playing ? { playing: false } : {};
    setPlaying(false);
    setFrame(Number($("frame").value), extra);
    sendView(true);
    scheduleUrlUpdate();
  }

  // --- light direction (assets with light states) ----------------------------------------------
  // A ball: a point on it is where the light comes from as seen from the camera (centre: from
  // behind the camera, rim: from the side). The direction goes to the server in world space, a
  // settings message `light` of its own, and into the link as `light=x,y,z`; "Baked light"
  // clears it. Shown for assets baked with --lights (they have an `ambient` state).
  function hasLightStates(asset) { return (asset.states || []).includes("ambient"); }

  function cameraBasis() {
    const v = currentView();
    const f = norm(sub(v.target, v.eye));
    const r = norm(cross(f, [0, 1, 0]));
    return { right: r, up: cross(r, f), back: [-f[0], -f[1], -f[2]] };
  }

  function drawLightPad() {
    const pad = $("lightpad");
    const g = pad.getContext("2d");
    const c = pad.width / 2, rad = c - 4;
    g.clearRect(0, 0, pad.width, pad.height);
    let lx = 0.45, ly = 0.55;
    if (state.light) {
      const b = cameraBasis();
      const dot = (a, d) => a[0] * d[0] + a[1] * d[1] + a[2] * d[2];
      lx = dot(state.light, b.right); ly = dot(state.light, b.up);
    }
    const shade = g.createRadialGradient(c + lx * rad * 0.6, c - ly * rad * 0.6, 2, c, c, rad);
    shade.addColorStop(0, state.light ? "#fff" : "#aaa");
    shade.addColorStop(1, "#222");
    g.fillStyle = shade;
    g.beginPath(); g.arc(c, c, rad, 0, 2 * Math.PI); g.fill();
    if (state.light) {
      g.strokeStyle = "#f80"; g.lineWidth = 2;
      g.beginPath(); g.arc(c + lx * rad, c - ly * rad, 4, 0, 2 * Math.PI); g.stroke();
    }
  }

  function fillLighting(asset, initial) {
    $("lighting").hidden = !hasLightStates(asset);
    state.light = !$("lighting").hidden && initial ? initial.slice() : null;
    if ($("lighting").hidden) delete state.extra.light;
    drawLightPad();
  }

  function setLight(light) {
    state.light = light;
    if (light) state.extra.light = light.map((x) => String(Number(x.toFixed(4)))).join(",");
    else delete state.extra.light;
    send({ type: "settings", light });
    drawLightPad();
    sendView(true);
    scheduleUrlUpdate();
  }

  function padLight(e) {
    const pad = $("lightpad");
    const box = pad.getBoundingClientRect();
    let x = ((e.clientX - box.left) / box.width) * 2 - 1;
    let y = 1 - ((e.clientY - box.top) / box.height) * 2;
    const r2 = x * x + y * y;
    if (r2 > 1) { const s = 1 / Math.sqrt(r2); x *= s; y *= s; }
    const z = Math.sqrt(Math.max(0, 1 - x * x - y * y));
    const b = cameraBasis();
    return norm([0, 1, 2].map((i) => x * b.right[i] + y * b.up[i] + z * b.back[i]));
  }

  let lightDrag = false;
  $("lightpad").addEventListener("pointerdown", (e) => {
    lightDrag = true;
    $("lightpad").setPointerCapture(e.pointerId);
    setLight(padLight(e));
  });
  $("lightpad").addEventListener("pointermove", (e) => { if (lightDrag) setLight(padLight(e)); });
  $("lightpad").addEventListener("pointerup", () => { lightDrag = false; });
  $("lightpad").addEventListener("pointercancel", () => { lightDrag = false; });
  $("light_reset").addEventListener("click", () => setLight(null));

  // --- the state in the URL ------------------------------------------------------------------
  // Precision (docs/protocol.md, "Viewer links"): angles to 0.001°, distance to 6 significant
  // digits, the target to 1e-6 of the distance; at 4096 px and 40° that moves a point by at most
  // about 0.05 px.
  const DEG = Math.PI / 180;
  const fmt = (v, decimals) => String(Number(v.toFixed(decimals)));
  const sig = (v, digits) => String(Number(v.toPrecision(digits)));
  const decimalsFor = (step) => Math.max(0, Math.min(12, Math.ceil(-Math.log10(step))));
  const CONTROL_DEFAULTS = {
    method: "default", still_codec: "jpeg", interactive: true, target_fps: 20, rest_ms: 250,
    background: [32, 32, 32, 255],
  };

  function cameraParams() {
    let az = (state.azimuth / DEG) % 360;
    if (az > 180) az -= 360; else if (az <= -180) az += 360;
    const td = decimalsFor(Math.abs(state.distance) * 1e-6);
    return [
      ["az", fmt(az, 3)],
      ["el", fmt(state.elevation / DEG, 3)],
      ["dist", sig(state.distance, 6)],
      ["target", state.target.map((v) => fmt(v, td)).join(",")],
      ["yfov_deg", fmt(state.yfovDeg, 3)],
    ];
  }

  // Quality keys the render link takes too; empty controls are left out.
  function qualityParams() {
    const out = [];
    if (isTwoPlane()) {
      if ($("uv_filter").value) out.push(["uv_filter", $("uv_filter").value]);
      for (const id of ["focus", "aperture"]) {
        const v = numberOrNull($(id));
        if (v !== null && v !== 0) out.push([id, sig(v, 6)]);
      }
      return out;
    }
    const lod = $("lod").value;
    if (lod && state.asset && Number(lod) !== state.asset.camera_count) out.push(["lod", lod]);
    if ($("method").value !== CONTROL_DEFAULTS.method) out.push(["method", $("method").value]);
    for (const id of ["step", "tolerance", "auto_lod"]) {
      const v = numberOrNull($(id));
      if (v !== null) out.push([id, String(v)]);
    }
    return out;
  }

  // The sliders' opacities for the image link (`layers=name:opacity,...`), if any.
  function layerParams() {
    const layers = Object.entries(layerOpacities());
    return layers.length ? [["layers", layers.map(([k, v]) => `${k}:${v}`).join(",")]] : [];
  }

  function viewerQuery() {
    const p = [["asset", state.asset ? state.asset.id : ""], ...cameraParams(), ...qualityParams()];
    if ($("still_codec").value !== CONTROL_DEFAULTS.still_codec) p.push(["still_codec", $("still_codec").value]);
    if (!$("interactive").checked) p.push(["interactive", "0"]);
    const fps = numberOrNull($("target_fps"));
    if (fps !== null && fps !== CONTROL_DEFAULTS.target_fps) p.push(["target_fps", String(fps)]);
    const rest = numberOrNull($("rest_ms"));
    if (rest !== null && rest !== CONTROL_DEFAULTS.rest_ms) p.push(["rest_ms", String(rest)]);
    const bg = backgroundRgba();
    if (bg.join() !== CONTROL_DEFAULTS.background.join()) p.push(["background", bg.join(",")]);
    for (const [k, v] of Object.entries(state.extra)) p.push([k, v]);
    if (state.warper && !reprojectBox.checked) p.push(["reproject", "0"]);
    return p;
  }

  // Keeps the reserved characters readable (`,` and `:` are safe in a query value).
  const encode = (v) => encodeURIComponent(v).replace(/%2C/gi, ",").replace(/%3A/gi, ":");
  const toQuery = (pairs) => pairs.map(([k, v]) => `${k}=${encode(v)}`).join("&");

  /** The link to this view: the viewer page with the whole state. */
  function link() {
    return `${location.origin}${location.pathname}?${toQuery(viewerQuery())}`;
  }

  /** The image of this view: `GET /v1/assets/{id}/render` with the same camera and quality. */
  function imageLink() {
    const [w, h] = viewSize();
    const p = [...cameraParams(), ["width", String(w)], ["height", String(h)],
      ...qualityParams(), ...layerParams(), ["background", backgroundRgba().join(",")], ["format", "png"]];
    const id = state.asset ? state.asset.id : "";
    return `${location.origin}/v1/assets/${encodeURIComponent(id)}/render?${toQuery(p)}`;
  }
  state.link = link;
  state.imageLink = imageLink;

  // The URL follows the view at most every 250 ms (replaceState: no history entry per move).
  let urlTimer = null;
  function scheduleUrlUpdate() {
    if (urlTimer !== null || !state.asset) return;
    urlTimer = setTimeout(() => {
      urlTimer = null;
      history.replaceState(null, "", `${location.pathname}?${toQuery(viewerQuery())}`);
    }, 250);
  }

  // The URL's state, checked key by key: a bad value is reported and its default used.
  const URL_KEYS = ["asset", "az", "el", "dist", "target", "yfov_deg", "lod", "method", "step",
    "tolerance", "auto_lod", "still_codec", "interactive", "target_fps", "rest_ms", "background",
    "layers", "state", "light", "time", "playing", "uv_filter", "focus", "aperture", "reproject"];
  const UV_FILTERS = ["nearest", "bilinear", "dither", "depth"];

  function readUrl() {
    const params = new URLSearchParams(location.search);
    const out = { problems: [], camera: {}, controls: {}, settings: {}, extra: {}, twoPlane: {} };
    const bad = (k, v, why) => out.problems.push(`${k}=${v}: ${why}; using the default`);
    const num = (k, v, lo, hi) => {
      const x = v.trim() === "" ? NaN : Number(v);
      if (!Number.isFinite(x)) { bad(k, v, "not a number"); return null; }
      if (x < lo || x > hi) { bad(k, v, `outside [${lo}, ${hi}]`); return null; }
      return x;
    };
    const seen = new Set();
    for (const [k, v] of params) {
      if (seen.has(k)) { out.problems.push(`${k} is given more than once; using the first`); continue; }
      seen.add(k);
      if (!URL_KEYS.includes(k)) { out.problems.push(`unknown key ${k}; ignored`); continue; }
      switch (k) {
        case "asset": out.asset = v; break;
        // Read at start-up (the reprojection switch); here only checked.
        case "reproject": if (v !== "0" && v !== "1") bad(k, v, "not 0 or 1"); break;
        case "az": { const x = num(k, v, -1e6, 1e6); if (x !== null) out.camera.azimuth = x * DEG; break; }
        case "el": { const x = num(k, v, -88.8, 88.8); if (x !== null) out.camera.elevation = x * DEG; break; }
        case "dist": { const x = num(k, v, 1e-6, 1e12); if (x !== null) out.camera.distance = x; break; }
        case "yfov_deg": { const x = num(k, v, 0.01, 179); if (x !== null) out.camera.yfovDeg = x; break; }
        case "target": {
          const t = v.split(",").map((c) => (c.trim() === "" ? NaN : Number(c)));
          if (t.length !== 3 || !t.every(Number.isFinite)) bad(k, v, "not three numbers x,y,z");
          else out.camera.target = t;
          break;
        }
        case "lod": {
          const x = num(k, v, 1, 642);
          if (x !== null && [12, 42, 162, 642].includes(x)) out.controls.lod = String(x);
          else if (x !== null) bad(k, v, "not a camera count (12, 42, 162, 642)");
          break;
        }
        case "method":
          if (["default", "fixed"].includes(v)) out.controls.method = v; else bad(k, v, "not default or fixed");
          break;
        case "step": { const x = num(k, v, 1 / 4096, 1); if (x !== null) out.controls.step = String(x); break; }
        case "tolerance": { const x = num(k, v, 1e-9, 1); if (x !== null) out.controls.tolerance = String(x); break; }
        case "auto_lod": { const x = num(k, v, 0.05, 100); if (x !== null) out.controls.auto_lod = String(x); break; }
        case "still_codec":
          if (["jpeg", "png", "webp"].includes(v)) out.controls.still_codec = v; else bad(k, v, "not jpeg, png or webp");
          break;
        case "interactive":
          if (v === "0" || v === "1") out.controls.interactive = v === "1"; else bad(k, v, "not 0 or 1");
          break;
        case "target_fps": { const x = num(k, v, 1, 120); if (x !== null) out.controls.target_fps = String(x); break; }
        case "rest_ms": { const x = num(k, v, 0, 10000); if (x !== null) out.controls.rest_ms = String(x); break; }
        case "background": {
          const c = v.split(",").map((x) => (/^\d{1,3}$/.test(x) ? Number(x) : NaN));
          if (c.length !== 4 || !c.every((x) => x <= 255)) bad(k, v, "not r,g,b,a in 0..255");
          else out.controls.background = "#" + c.slice(0, 3).map((x) => x.toString(16).padStart(2, "0")).join("");
          break;
        }
        case "layers": {
          // name:opacity,name:opacity; the server checks names and opacities against the asset.
          const layers = {};
          let ok = v !== "";
          for (const item of v.split(",")) {
            const i = item.lastIndexOf(":");
            const o = i > 0 ? Number(item.slice(i + 1)) : NaN;
            if (!Number.isFinite(o)) { ok = false; break; }
            layers[item.slice(0, i)] = o;
          }
          if (ok) { out.settings.layers = layers; out.extra.layers = v; } else bad(k, v, "not name:opacity,...");
          break;
        }
        case "state": out.settings.state = v; out.extra.state = v; break;
        // Seconds into the animation; the server checks it against the asset's animation.
        case "time": { const x = num(k, v, 0, 1e6); if (x !== null) { out.settings.time = x; out.extra.time = v; } break; }
        case "playing":
          if (v === "1" || v === "0") { out.settings.playing = v === "1"; if (v === "1") out.extra.playing = v; } else bad(k, v, "not 0 or 1");
          break;
        case "light": {
          const l = v.split(",").map((c) => (c.trim() === "" ? NaN : Number(c)));
          if (l.length !== 3 || !l.every(Number.isFinite) || Math.hypot(l[0], l[1], l[2]) === 0) {
            bad(k, v, "not a non-zero direction x,y,z");
          } else {
            out.settings.light = norm(l); out.extra.light = v;
          }
          break;
        }
        // Two-plane keys: checked against the asset's planes once it is known.
        case "uv_filter":
          if (UV_FILTERS.includes(v)) out.twoPlane.uv_filter = v; else bad(k, v, `not one of ${UV_FILTERS.join(", ")}`);
          break;
        case "focus": { const x = num(k, v, -1e12, 1e12); if (x !== null) out.twoPlane.focus = x; break; }
        case "aperture": { const x = num(k, v, 0, 64); if (x !== null) out.twoPlane.aperture = x; break; }
        default: break;
      }
    }
    return out;
  }

  function applyControls(controls) {
    for (const [id, value] of Object.entries(controls)) {
      if (id === "lod") continue;
      if (id === "interactive") $(id).checked = value; else $(id).value = value;
    }
  }

  function parseHeader(buf) {
    const dv = new DataView(buf);
    const magic = String.fromCharCode(dv.getUint8(0), dv.getUint8(1), dv.getUint8(2), dv.getUint8(3));
    if (magic !== "LGF1") throw new Error("bad frame magic " + magic);
    const vec3 = (at) => [dv.getFloat32(at, true), dv.getFloat32(at + 4, true), dv.getFloat32(at + 8, true)];
    // Byte 38: JPEG quality; byte 39: flags (bit 0 adapted to the link, bit 1 still sent as
    // JPEG, bit 2 the depth extension follows the 40-byte header; docs/protocol.md).
    const flags = dv.getUint8(39);
    const depth = flags & 4 ? {
      codec: dv.getUint8(40),
      colorBytes: dv.getUint32(44, true),
      near: dv.getFloat32(48, true),
      far: dv.getFloat32(52, true),
      eye: vec3(56),
      target: vec3(68),
      up: vec3(80),
      yfovDeg: dv.getFloat32(92, true),
      depthBytes: dv.getUint32(96, true),
    } : null;
    // Bit 3: the animation extension (frame index, time) follows the depth extension, if any.
    const at = 40 + (flags & 4 ? 60 : 0);
    const animation = flags & 8 ? { frame: dv.getUint32(at, true), time: dv.getFloat32(at + 4, true) } : null;
    return {
      depth,
      animation,
      headerLen: dv.getUint16(4, true),
      codec: dv.getUint8(6),
      quality: dv.getUint8(7),
      frameId: dv.getUint32(8, true),
      requestId: dv.getUint32(12, true),
      width: dv.getUint32(16, true),
      height: dv.getUint32(20, true),
      renderMs: dv.getFloat32(24, true),
      encodeMs: dv.getFloat32(28, true),
      dropped: dv.getUint32(32, true),
      cameras: dv.getUint16(36, true),
      encodedQuality: dv.getUint8(38),
      flags,
      bytes: buf.byteLength,
    };
  }

  async function onFrame(buf) {
    const h = parseHeader(buf);
    const colorEnd = h.depth ? h.headerLen + h.depth.colorBytes : buf.byteLength;
    const blob = new Blob([buf.slice(h.headerLen, colorEnd)], { type: CODECS[h.codec] || "image/png" });
    const bitmap = await createImageBitmap(blob, { premultiplyAlpha: "none", colorSpaceConversion: "none" });
    const shows = state.seqOfRequest.get(h.requestId) ?? -1;
    if (reprojecting() && h.depth && h.depth.codec === 1) {
      const d = h.depth;
      const decoded = await window.LumigraphReproject.decodePng16(
        new Uint8Array(buf, colorEnd, d.depthBytes), d.near, d.far);
      state.warper.push(bitmap, decoded, { eye: d.eye, target: d.target, up: d.up, yfov_deg: d.yfovDeg });
    }
    // A frame for an older camera than the current one is drawn reprojected to it (it is still
    // the newest picture); the frame for the current camera replaces any warped one.
    if (!(shows < state.cameraSeq && drawWarped())) {
      present(bitmap, false);
      logEntry(state.draws, { kind: "frame", seq: shows, t: performance.now() });
    }
    bitmap.close();
    const now = performance.now();
    state.frames += 1;
    state.frameTimes.push(now);
    while (state.frameTimes.length && now - state.frameTimes[0] > 1000) state.frameTimes.shift();
    const sent = state.sentAt.get(h.requestId);
    h.latencyMs = sent === undefined ? null : now - sent;
    state.last = h;
    if (h.animation && state.playing) showFrame(h.animation.frame);
    updateStats();
  }

  function updateStats() {
    const h = state.last;
    statsEl.dataset.frames = String(state.frames);
    if (!h) { statsEl.textContent = "waiting for the first frame…"; return; }
    statsEl.dataset.quality = QUALITY[h.quality] || String(h.quality);
    statsEl.textContent = [
      `fps       ${state.frameTimes.length}`,
      `render    ${h.renderMs.toFixed(1)} ms`,
      `encode    ${h.encodeMs.toFixed(1)} ms`,
      `latency   ${h.latencyMs === null ? "-" : h.latencyMs.toFixed(0) + " ms"}`,
      `bytes     ${(h.bytes / 1024).toFixed(1)} KiB`,
      `quality   ${QUALITY[h.quality] || h.quality} ${h.width}x${h.height} ${CODECS[h.codec] || "?"}`,
      `cameras   ${h.cameras}`,
      ...(h.animation ? [`anim      frame ${h.animation.frame} (${h.animation.time.toFixed(2)} s)`] : []),
      `frames    ${state.frames} (dropped ${h.dropped})`,
      `reproject ${reprojecting() ? "on" : state.warper ? "off" : "off (no WebGL2)"} (${state.warps} warped)`,
    ].join("\n");
  }

  function fillLod(count) {
    const lod = $("lod");
    lod.innerHTML = "";
    for (const n of [12, 42, 162, 642].filter((n) => n <= count)) {
      const o = document.createElement("option");
      o.value = String(n); o.textContent = String(n);
      lod.appendChild(o);
    }
    lod.value = String(count);
  }

  function resetCamera() {
    const a = state.asset;
    if (a && a.planes) {
      // On the axis, half the plane separation behind the uv plane, looking at the st centre:
      // every pixel's ray crosses both planes near the middle of the light field.
      const st = a.planes.st.center, uv = a.planes.uv.center;
      const d = sub(uv, st);
      const sep = Math.hypot(d[0], d[1], d[2]) || 1;
      state.target = st.slice();
      state.distance = 1.5 * sep;
      state.azimuth = Math.atan2(d[0], d[2]);
      state.elevation = Math.asin(Math.max(-1, Math.min(1, d[1] / sep)));
      return;
    }
    state.target = a ? a.center.slice() : [0, 0, 0];
    state.distance = a ? a.radius * 2.8 : 3;
    state.azimuth = 0.6;
    state.elevation = 0.35;
  }

  // --- two-plane controls: uv filter, focus and aperture sliders --------------------------------
  // Shown for a two-plane light field in place of the marcher's knobs. Focus runs over the
  // separation of the planes either side of st; the aperture up to half the wider uv grid.
  function fillTwoPlane(asset, initial, problems) {
    const two = asset.kind === "two_plane" && asset.planes;
    $("two_plane_controls").hidden = !two;
    $("spherical_controls").hidden = !!two;
    if (!two) {
      for (const [k, v] of Object.entries(initial)) {
        problems.push(`${k}=${v}: applies to two-plane light fields; ignored`);
      }
      return;
    }
    const p = asset.planes;
    const sep = Math.hypot(...sub(p.uv.center, p.st.center));
    const focus = $("focus");
    focus.min = String(-sep);
    focus.max = String(0.95 * sep);
    focus.step = String(sep / 1000);
    const aperture = $("aperture");
    aperture.max = String(Math.min(64, Math.max(1, Math.floor(Math.max(...p.uv.grid) / 2))));
    $("uv_filter").value = initial.uv_filter || "";
    const clampTo = (el, x) => Math.max(Number(el.min), Math.min(Number(el.max), x));
    if (initial.focus !== undefined && clampTo(focus, initial.focus) !== initial.focus) {
      problems.push(`focus=${initial.focus}: outside [${fmt(-sep, 4)}, ${fmt(0.95 * sep, 4)}]; clamped`);
    }
    focus.value = String(clampTo(focus, initial.focus ?? 0));
    aperture.value = String(clampTo(aperture, initial.aperture ?? 0));
    showTwoPlaneLabels();
  }

  function showTwoPlaneLabels() {
    $("focus_label").textContent = sig(Number($("focus").value), 4);
    $("aperture_label").textContent = $("aperture").value;
  }

  function connect(assetId) {
    state.idleAsset = null;
    if (state.ws) { state.ws.onclose = null; state.ws.close(); }
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const ws = new WebSocket(`${proto}//${location.host}/v1/stream?asset=${encodeURIComponent(assetId)}`);
    ws.binaryType = "arraybuffer";
    state.ws = ws;
    statsEl.textContent = "connecting…";
    ws.onmessage = (ev) => {
      if (typeof ev.data !== "string") {
        // Ack at once, before decoding and behind no earlier frame's drawing: the server renders
        // the next frame meanwhile, and measures the link from these receive times.
        if (ev.data.byteLength >= 12) {
          send({ type: "ack", frame: new DataView(ev.data).getUint32(8, true), received_ms: performance.now() });
        }
        state.drawing = state.drawing.then(() => onFrame(ev.data)).catch((e) => showError(String(e)));
        return;
      }
      const msg = JSON.parse(ev.data);
      if (msg.type === "hello") {
        const same = state.asset && state.asset.id === msg.asset.id;
        state.asset = msg.asset;
        state.maxPx = msg.max_px;
        fillLod(msg.asset.camera_count);
        fillLayers(msg.asset, fromUrlLayers());
        fillStates(msg.asset, (state.fromUrl && state.fromUrl.settings.state) || (same ? state.extra.state : null));
        fillPlayback(msg.asset, state.fromUrl ? state.fromUrl.settings.playing : (same && state.playing),
          state.fromUrl ? state.fromUrl.settings.time : (same && state.extra.time ? Number(state.extra.time) : null));
        // The link's light, else (a reconnect to the same asset) the light already chosen.
        fillLighting(msg.asset, (state.fromUrl && state.fromUrl.settings.light) || (same ? state.light : null));
        if (!same) resetCamera();
        const fromUrl = state.fromUrl;
        state.fromUrl = null;
        const kept = same ? { uv_filter: $("uv_filter").value || undefined, focus: numberOrNull($("focus")) ?? undefined,
          aperture: numberOrNull($("aperture")) ?? undefined } : {};
        const twoPlaneProblems = [];
        fillTwoPlane(msg.asset, fromUrl ? fromUrl.twoPlane : (msg.asset.kind === "two_plane" ? kept : {}), twoPlaneProblems);
        if (fromUrl) fromUrl.problems.push(...twoPlaneProblems);
        if (fromUrl) {
          Object.assign(state, fromUrl.camera);
          if (fromUrl.controls.lod !== undefined) {
            if (Number(fromUrl.controls.lod) <= msg.asset.camera_count) $("lod").value = fromUrl.controls.lod;
            else fromUrl.problems.push(`lod=${fromUrl.controls.lod}: the asset has ${msg.asset.camera_count} cameras; using all`);
          }
          showNotice(fromUrl.problems);
        }
        sendSettings();
        // Layers and state go in a settings message of their own: one the asset refuses (an
        // error shown below) leaves the other settings applied.
        if (fromUrl && Object.keys(fromUrl.settings).length) send({ type: "settings", ...fromUrl.settings });
        else {
          // A reconnect keeps the light and state already chosen.
          const again = {};
          if (state.light) again.light = state.light;
          if (state.extra.state) again.state = state.extra.state;
          if (state.playing) again.playing = true;
          else if (state.extra.time) again.time = Number(state.extra.time);
          if (Object.keys(again).length) send({ type: "settings", ...again });
        }
        sendView(true);
      } else if (msg.type === "error") {
        showError(`${msg.kind}: ${msg.message}`);
      }
    };
    ws.onclose = (ev) => {
      if (state.ws !== ws) return;
      if (ev.code === 1008 && ev.reason.startsWith("idle")) {
        state.idleAsset = assetId;
        statsEl.textContent = "paused while idle; move the view to resume";
        return;
      }
      statsEl.textContent = `disconnected (${ev.code}${ev.reason ? " " + ev.reason : ""}); reconnecting…`;
      setTimeout(() => { if (state.ws === ws) connect(assetId); }, 1500);
    };
  }

  async function loadAssets() {
    const res = await fetch("/v1/assets");
    if (!res.ok) throw new Error(`GET /v1/assets: ${res.status}`);
    const assets = await res.json();
    const sel = $("asset");
    sel.innerHTML = "";
    for (const a of assets) {
      const o = document.createElement("option");
      o.value = a.id;
      o.textContent = `${a.id} (${a.camera_count} cams, ${a.resolution_px}px)`;
      sel.appendChild(o);
    }
    if (!assets.length) { statsEl.textContent = "no assets yet (the demo may still be baking)…"; setTimeout(boot, 2000); return; }
    const fromUrl = readUrl();
    let id = assets[0].id;
    if (fromUrl.asset !== undefined) {
      if (assets.some((a) => a.id === fromUrl.asset)) id = fromUrl.asset;
      else {
        fromUrl.problems.unshift(`asset=${fromUrl.asset}: no such asset; showing ${id} instead`);
        // A camera placed for another asset means nothing here: start from this one's default.
        fromUrl.camera = {};
      }
    }
    sel.value = id;
    applyControls(fromUrl.controls);
    state.extra = fromUrl.extra;
    state.fromUrl = fromUrl;
    showNotice(fromUrl.problems);
    connect(id);
  }

  function boot() { loadAssets().catch((e) => { showError(String(e)); setTimeout(boot, 2000); }); }

  // --- input: orbit, pan, zoom -------------------------------------------------------------
  let drag = null;
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("pointerdown", (e) => {
    drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey };
    canvas.setPointerCapture(e.pointerId);
    canvas.classList.add("dragging");
  });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      // Move the target in the view plane, scaled so the object follows the pointer.
      const { right: r, up: u } = cameraBasis();
      const perPx = (2 * state.distance * Math.tan((state.yfovDeg * Math.PI) / 360)) / Math.max(1, canvas.clientHeight);
      for (let i = 0; i < 3; i++) state.target[i] += (-dx * r[i] + dy * u[i]) * perPx;
    } else {
      state.azimuth -= dx * 0.008;
      state.elevation = Math.max(-1.55, Math.min(1.55, state.elevation + dy * 0.008));
    }
    requestView(false);
  });
  const endDrag = () => { drag = null; canvas.classList.remove("dragging"); };
  canvas.addEventListener("pointerup", endDrag);
  canvas.addEventListener("pointercancel", endDrag);
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    state.distance = Math.max(1e-3, state.distance * Math.exp(e.deltaY * 0.001));
    requestView(false);
  }, { passive: false });
  canvas.addEventListener("dblclick", () => { resetCamera(); requestView(false); });
  window.addEventListener("resize", () => requestView(false));

  reprojectBox.addEventListener("change", () => { if (!reprojectBox.checked && state.warper) state.warper.clear(); });
  for (const id of ["lod", "method", "step", "tolerance", "auto_lod", "still_codec", "interactive", "target_fps", "rest_ms", "background", "reproject", "uv_filter", "accumulate"]) {
    $(id).addEventListener("change", () => { sendSettings(); requestView(false); });
  }
  // Focus and aperture move like the camera: interactive frames while dragged, a still at rest.
  for (const id of ["focus", "aperture"]) {
    $(id).addEventListener("input", () => { showTwoPlaneLabels(); sendSettings(); requestView(false); });
  }
  $("asset").addEventListener("change", (e) => { state.extra = {}; connect(e.target.value); });
  $("state").addEventListener("change", sendState);
  $("play").addEventListener("click", togglePlayback);
  $("frame").addEventListener("input", scrubFrame);
  $("notice").addEventListener("click", () => showNotice([]));

  // Copy buttons: the clipboard where the page may use it, else the text is selected in a
  // prompt-free field for the user to copy.
  async function copy(text, button) {
    state.copied = text;
    const label = button.textContent;
    try {
      await navigator.clipboard.writeText(text);
      button.textContent = "Copied";
    } catch {
      const field = $("copied");
      field.style.display = "block";
      field.value = text;
      field.select();
      button.textContent = "Select and copy below";
    }
    setTimeout(() => { button.textContent = label; }, 1500);
  }
  $("copy_link").addEventListener("click", (e) => copy(link(), e.currentTarget));
  $("copy_image_link").addEventListener("click", (e) => copy(imageLink(), e.currentTarget));

  // For tests and the console: orbit as a drag does, the current view, a warped draw now.
  state.orbit = (dAzimuth) => { state.azimuth += dAzimuth; requestView(false); };
  state.currentView = currentView;
  state.drawWarped = drawWarped;

  function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function norm(a) { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; }

  boot();
})();
