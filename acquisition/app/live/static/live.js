// msflash live: draws what the server says (GET /api/state, pushed on the WebSocket) and sends every
// change as a POST carrying the session token. The page keeps no state of its own: a reload loses nothing.
"use strict";
const token = document.querySelector('meta[name="msflash-token"]').content;
const $ = (id) => document.getElementById(id);
let state = null;
let shownRun = null;
const frameUrls = {};
const EXPOSURE_STEPS = 1000;
let socket = null;
let closedReason = "";
const liveArrivals = [];
let lastLiveN = null;
let dropped = 0;
let mixLevels = null;
let mixPosting = false;
let mixPending = null;
let mixFrames = 0;

function showError(text) {
  const el = $("error");
  el.hidden = !text;
  el.textContent = text || "";
}

async function post(path, body) {
  const response = await fetch(path, {
    method: "POST",
    headers: { "Content-Type": "application/json", "X-Msflash-Token": token },
    body: JSON.stringify(body || {}),
  });
  const reply = await response.json().catch(() => ({}));
  if (!response.ok) { showError(reply.error || response.statusText); return null; }
  showError(null);
  if (reply.rig) render(reply);
  return reply;
}

// Exposure slider: logarithmic over the camera's range (clamped to 10 µs – 2 s for the page).
function exposureRange() {
  const [low, high] = state.exposure_range_us;
  return [Math.max(low, 10), Math.min(high, 2e6)];
}
function exposureToSlider(us) {
  const [low, high] = exposureRange();
  return Math.round(EXPOSURE_STEPS * Math.log(us / low) / Math.log(high / low));
}
function sliderToExposure(position) {
  const [low, high] = exposureRange();
  return Math.round(low * Math.pow(high / low, position / EXPOSURE_STEPS));
}
function formatGain(linear, native) {
  const db = 20 * Math.log10(linear);
  const both = `${linear.toFixed(2)}× · ${db.toFixed(1)} dB`;
  if (native && native.unit === "dB") return `${db.toFixed(1)} dB (${linear.toFixed(2)}×)`;
  if (native && native.unit === "raw") return `${native.feature} ${native.value} (${both})`;
  return `${linear.toFixed(2)}× (${db.toFixed(1)} dB)`;
}
function formatUs(us) { return us >= 1000 ? (us / 1000).toFixed(us >= 1e5 ? 0 : 1) + " ms" : us.toFixed(0) + " µs"; }

function buildLeds() {
  const box = $("leds");
  box.textContent = "";
  state.leds.forEach((led, i) => {
    const row = document.createElement("div");
    row.className = "led";
    row.innerHTML = `<span title="peak ${led.peak_nm.toFixed(0)} nm">${led.name}</span>
      <input type="range" min="0" max="100" step="1" id="led-${i}" data-channel="${i}">
      <output id="led-${i}-value"></output><span class="booth" id="led-${i}-booth"></span>`;
    box.appendChild(row);
    const slider = row.querySelector("input");
    slider.addEventListener("input", () => { $(`led-${i}-value`).textContent = slider.value + "%"; });
    slider.addEventListener("change", () => post("/api/levels", { channel: i, level: Number(slider.value) / 100 }));
  });
}

function setIfIdle(element, value) { if (document.activeElement !== element) element.value = value; }

function render(next) {
  const first = state === null || state.leds.length !== next.leds.length;
  state = next;
  if (first) buildLeds();
  $("rig").textContent = `rig ${state.rig} · ${state.camera}`;
  showError(state.error);
  $("lost").textContent = state.lost_frames ? `${state.lost_frames} incomplete frame(s) taken again` : "";
  setIfIdle($("exposure"), exposureToSlider(state.exposure_us));
  $("exposure-value").textContent = formatUs(state.exposure_us);
  setIfIdle($("gain"), state.gain);
  $("gain-value").textContent = formatGain(state.gain, state.camera_gain);
  renderFormat(state.camera_format);
  $("overlay").checked = state.overlay;
  setIfIdle($("sequence-exposure"), state.sequence_exposure);
  setIfIdle($("mode"), state.mode);
  state.levels.forEach((level, i) => {
    setIfIdle($(`led-${i}`), Math.round(level * 100));
    $(`led-${i}-value`).textContent = Math.round(level * 100) + "%";
  });
  showBooth(state.booth_levels);
  renderJob(state.job);
  renderRuns(state.runs);
  renderMix(state.mix);
  showDisconnected();
}

// ROI, binning and pixel format: what the camera allows (its features' limits), each change a POST; a refusal's
// one-line reason is shown under the controls.
function renderFormat(camera) {
  const box = $("camera-format");
  if (!camera) { box.textContent = ""; return; }
  box.textContent = camera.summary;
  box.dataset.pixelFormat = camera.pixel_format;
  box.dataset.width = camera.width;
  box.dataset.height = camera.height;
  const limits = camera.limits || {};
  const image = camera.format || { roi: [0, 0, camera.width, camera.height], binning: [1, 1], pixel_format: camera.pixel_format };
  const lock = (element, feature) => {
    const entry = limits[feature];
    element.disabled = !entry || !entry.available;
    element.title = !entry ? "the camera cannot say" : entry.available ? `${feature}: ${entry.allowed}` : entry.why;
  };
  const formats = $("pixel-format");
  const entries = (limits.PixelFormat && limits.PixelFormat.entries) || [image.pixel_format];
  if (formats.dataset.entries !== entries.join()) {
    formats.dataset.entries = entries.join();
    formats.textContent = "";
    entries.forEach((name) => formats.add(new Option(name, name)));
  }
  setIfIdle(formats, image.pixel_format);
  lock(formats, "PixelFormat");
  const binning = $("binning");
  const most = Math.max(1, ...["BinningHorizontal", "BinningVertical"].map((f) => (limits[f] && limits[f].maximum) || 1));
  if (binning.dataset.most !== String(most)) {
    binning.dataset.most = most;
    binning.textContent = "";
    for (let k = 1; k <= most; k++) binning.add(new Option(`${k} × ${k}`, `${k}x${k}`));
    if (most > 1) binning.add(new Option(`${most} × 1`, `${most}x1`));
  }
  const current = `${image.binning[0]}x${image.binning[1]}`;
  if (![...binning.options].some((o) => o.value === current)) binning.add(new Option(current.replace("x", " × "), current));
  setIfIdle(binning, current);
  lock(binning, "BinningHorizontal");
  ["x", "y", "w", "h"].forEach((key, i) => {
    const input = $(`roi-${key}`);
    const feature = ["OffsetX", "OffsetY", "Width", "Height"][i];
    const entry = limits[feature];
    if (entry && entry.increment) input.step = entry.increment;
    if (entry && entry.maximum != null) input.max = entry.maximum;
    setIfIdle(input, image.roi[i]);
    lock(input, feature);
  });
  $("roi-apply").disabled = $("roi-w").disabled && $("roi-h").disabled;
  $("roi-full").disabled = $("roi-apply").disabled;
}
async function postFormat(body) {
  const message = $("format-message");
  message.textContent = "setting…";
  message.className = "format-message";
  const response = await fetch("/api/camera-format", {
    method: "POST",
    headers: { "Content-Type": "application/json", "X-Msflash-Token": token },
    body: JSON.stringify(body),
  }).catch(() => null);
  const reply = response ? await response.json().catch(() => ({})) : { error: "the server does not answer" };
  if (!response || !response.ok) { message.textContent = reply.error || response.statusText; message.dataset.refused = "1"; return; }
  message.dataset.refused = "";
  message.className = "format-message ok";
  message.textContent = `set: ${reply.camera_format.summary}`;
  render(reply);
}
$("pixel-format").addEventListener("change", () => postFormat({ pixel_format: $("pixel-format").value }));
$("binning").addEventListener("change", () => postFormat({ binning: $("binning").value.split("x").map(Number) }));
$("roi-apply").addEventListener("click", () => postFormat({ roi: ["x", "y", "w", "h"].map((k) => Math.round(Number($(`roi-${k}`).value))) }));
$("roi-full").addEventListener("click", () => {
  const sensor = (state.camera_format.limits || {}).sensor || [state.camera_format.width, state.camera_format.height];
  const width = state.camera_format.limits && state.camera_format.limits.Width ? state.camera_format.limits.Width : null;
  const step = width && width.increment ? width.increment : 1;
  postFormat({ roi: [0, 0, Math.floor(sensor[0] / step) * step, sensor[1]] });
});

function showBooth(levels) {
  if (!levels) return;
  levels.forEach((level, i) => {
    const el = $(`led-${i}-booth`);
    if (el) { el.textContent = `booth ${(level * 100).toFixed(0)}%`; el.dataset.level = level; }
  });
}

function renderJob(job) {
  const box = $("job");
  box.dataset.status = job.status;
  box.dataset.run = job.run || "";
  $("job-phase").textContent = job.status === "idle" ? "" : `${job.run}: ${job.phase}`;
  $("job-progress").max = Math.max(job.total, 1);
  $("job-progress").value = job.landed;
  const list = $("job-steps");
  list.textContent = "";
  job.steps.forEach((step) => {
    const item = document.createElement("li");
    item.textContent = step.label;
    if (step.file) { item.className = "landed"; item.title = step.file; }
    list.appendChild(item);
  });
  $("job-message").textContent = job.message;
  $("fire").disabled = job.status === "running";
  if (job.status === "done" && job.run && job.run !== shownRun) showRun(job.run);
}

async function showRun(name) {
  shownRun = name;
  let run = null;
  try {
    const response = await fetch(`/api/runs/${encodeURIComponent(name)}`, { headers: { "X-Msflash-Token": token } });
    if (response.ok) run = await response.json();
  } catch (err) { run = null; }
  if (!run) {  // the server did not answer (busy, or gone for a moment): ask again
    if (shownRun === name) shownRun = null;
    setTimeout(() => { if (shownRun === null) showRun(name); }, 2000);
    return;
  }
  const link = $("result-link");
  link.href = `/runs/${encodeURIComponent(name)}/`;
  link.textContent = `report of ${name}`;
  link.hidden = false;
  $("charts").innerHTML = run.charts ? run.charts.ambient + run.charts.mixes : "";
  const previews = $("previews");
  previews.textContent = "";
  ["ambient.png", "matching.png", "complementary.png", "flash-capture.png"].filter((f) => run.files.includes(f))
    .forEach((file) => {
      const figure = document.createElement("figure");
      const img = document.createElement("img");
      img.src = `/runs/${encodeURIComponent(name)}/files/${file}`;
      img.alt = file;
      figure.appendChild(img);
      const caption = document.createElement("figcaption");
      caption.textContent = file.replace(".png", "");
      figure.appendChild(caption);
      previews.appendChild(figure);
    });
  $("result").dataset.run = name;
}

function renderRuns(runs) {
  const list = $("run-list");
  list.textContent = "";
  runs.forEach((run) => {
    const item = document.createElement("li");
    const link = document.createElement("a");
    link.href = `/runs/${encodeURIComponent(run.name)}/`;
    link.target = "_blank";
    link.textContent = run.name;
    item.appendChild(link);
    if (run.spectrum_rmse_vs_truth != null) item.append(` · RMSE ${run.spectrum_rmse_vs_truth.toFixed(3)}`);
    else if (!run.reported) item.append(" · no report");
    list.appendChild(item);
  });
}

function drawHistogram(histogram) {
  ["r", "g", "b"].forEach((channel, c) => {
    const counts = histogram[c];
    const peak = Math.log1p(Math.max(...counts)) || 1;
    const step = 256 / counts.length;
    const points = counts.map((n, i) => `${(i + 0.5) * step},${80 - 78 * Math.log1p(n) / peak}`).join(" ");
    $(`hist-${channel}`).setAttribute("points", points);
  });
}

const VIEW_IMAGES = { live: "live", mix: "mix-image", "mix-ambient": "mix-ambient", "mix-capture": "mix-capture" };

function showImage(id, blob) {
  const url = URL.createObjectURL(blob);
  const img = $(id);
  img.onload = () => { if (frameUrls[id] && frameUrls[id] !== url) URL.revokeObjectURL(frameUrls[id]); frameUrls[id] = url; };
  img.src = url;
}

function onFrame(buffer) {
  const view = new DataView(buffer);
  const length = view.getUint32(0, true);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, length)));
  const blob = new Blob([new Uint8Array(buffer, 4 + length)], { type: "image/jpeg" });
  const target = header.view || "live";
  showImage(VIEW_IMAGES[target] || "live", blob);
  if (target === "mix") { mixFrames += 1; $("mix-frames").dataset.frames = mixFrames; $("mix-caption").textContent = header.source; }
  if (target === "mix-capture") $("mix-capture-figure").hidden = false;
  if (target !== "live" && !header.source.startsWith("sequence")) return;
  if (header.source === "live") countLive(header.live_n);
  if (header.raw_size) { $("frame-size").textContent = `${header.raw_size[0]} × ${header.raw_size[1]} px`; $("frame-size").dataset.size = header.raw_size.join("x"); }
  const count = $("frame-count");
  count.textContent = header.n;
  count.dataset.frames = header.n;
  $("frame-source").textContent = header.source;
  $("saturated").textContent = (100 * header.saturated).toFixed(2) + "%";
  drawHistogram(header.histogram);
  showBooth(header.booth_levels);
}

// fps over the last two seconds of live frames; dropped: gaps in the server's live frame numbers.
function countLive(n) {
  const now = performance.now();
  liveArrivals.push(now);
  while (liveArrivals.length && now - liveArrivals[0] > 2000) liveArrivals.shift();
  const span = (liveArrivals[liveArrivals.length - 1] - liveArrivals[0]) / 1000;
  const fps = liveArrivals.length > 1 && span > 0 ? (liveArrivals.length - 1) / span : 0;
  $("fps").textContent = fps.toFixed(1);
  $("fps").dataset.fps = fps;
  if (lastLiveN !== null && n > lastLiveN + 1) dropped += n - lastLiveN - 1;
  lastLiveN = n;
  $("dropped").textContent = dropped;
  $("dropped").dataset.dropped = dropped;
}

// Zoom and pan on the live image: the wheel zooms about the cursor, a drag pans, z toggles 1× / 4×.
const zoom = { k: 1, x: 0, y: 0, drag: null, cursor: null };
function applyZoom() {
  const vp = $("viewport");
  const w = vp.clientWidth, h = vp.clientHeight;
  zoom.x = Math.min(0, Math.max(w - w * zoom.k, zoom.x));
  zoom.y = Math.min(0, Math.max(h - h * zoom.k, zoom.y));
  $("live").style.transform = `translate(${zoom.x}px, ${zoom.y}px) scale(${zoom.k})`;
  vp.dataset.zoom = zoom.k;
  $("zoom-level").textContent = `${zoom.k.toFixed(zoom.k < 10 ? 1 : 0)}×`;
}
function zoomAbout(k, px, py) {
  const next = Math.min(32, Math.max(1, k));
  zoom.x = px - (px - zoom.x) * next / zoom.k;
  zoom.y = py - (py - zoom.y) * next / zoom.k;
  zoom.k = next;
  applyZoom();
}
function toggleZoom() {
  const vp = $("viewport");
  const [px, py] = zoom.cursor || [vp.clientWidth / 2, vp.clientHeight / 2];
  zoomAbout(zoom.k > 1 ? 1 : 4, px, py);
}
$("viewport").addEventListener("wheel", (event) => {
  event.preventDefault();
  const rect = $("viewport").getBoundingClientRect();
  zoomAbout(zoom.k * (event.deltaY < 0 ? 1.25 : 0.8), event.clientX - rect.left, event.clientY - rect.top);
}, { passive: false });
$("viewport").addEventListener("mousedown", (event) => { zoom.drag = [event.clientX - zoom.x, event.clientY - zoom.y]; });
window.addEventListener("mouseup", () => { zoom.drag = null; });
$("viewport").addEventListener("mousemove", (event) => {
  const rect = $("viewport").getBoundingClientRect();
  zoom.cursor = [event.clientX - rect.left, event.clientY - rect.top];
  if (zoom.drag) { zoom.x = event.clientX - zoom.drag[0]; zoom.y = event.clientY - zoom.drag[1]; applyZoom(); }
  readoutAt("live", $("live"), event);
});
$("zoom").addEventListener("click", toggleZoom);
$("mix-image").addEventListener("mousemove", (event) => readoutAt("mix", $("mix-image"), event));

// The pixel readout: the raw values per channel under the cursor, asked of the server (one request at a time).
let readoutBusy = false;
let readoutNext = null;
function readoutAt(view, img, event) {
  const rect = img.getBoundingClientRect();
  const x = (event.clientX - rect.left) / rect.width, y = (event.clientY - rect.top) / rect.height;
  if (!(x >= 0 && x <= 1 && y >= 0 && y <= 1)) return;
  readoutNext = { view, x, y };
  if (!readoutBusy) askReadout();
}
async function askReadout() {
  if (!readoutNext) return;
  const { view, x, y } = readoutNext;
  readoutNext = null;
  readoutBusy = true;
  try {
    const response = await fetch(`/api/pixel?view=${view}&x=${x.toFixed(5)}&y=${y.toFixed(5)}`, { headers: { "X-Msflash-Token": token } });
    const reply = await response.json();
    const box = $("readout");
    box.dataset.view = view;
    if (!response.ok) { box.textContent = reply.error; return; }
    const values = reply.channels.map((c) => `${c.channel} ${view === "live" ? c.value.toFixed(0) : c.value.toPrecision(4)}`).join("  ");
    box.textContent = `${view === "live" ? "live" : "synthesised"} · row ${reply.row}, column ${reply.column}: ${values} ${reply.unit}`;
    box.dataset.values = JSON.stringify(reply.channels.map((c) => c.value));
  } catch (err) { /* the server went away: the disconnected state says so */ }
  finally { readoutBusy = false; if (readoutNext) askReadout(); }
}

async function snapshot() {
  const reply = await post("/api/snapshot", {});
  if (reply) { $("snapshot-result").textContent = `saved ${reply.tiff} + ${reply.png}`; $("snapshot-result").dataset.tiff = reply.tiff; }
}
$("snapshot").addEventListener("click", snapshot);

// The disconnected state: the image greyed, the reason large on it, a reconnect button. A lost server
// ("Disconnected": the page reconnects its WebSocket) is told apart from a camera or booth that failed while the
// server stays ("Camera error": the server switched the LEDs off; reconnect asks it to take a frame again).
const ERROR_TITLES = { camera: "Camera error", booth: "Booth error" };
function showDisconnected() {
  const down = !socket || socket.readyState !== WebSocket.OPEN;
  const streamError = state && state.error ? state.error : "";
  const reason = down ? (closedReason || "connecting to the server…") : streamError;
  const box = $("disconnected");
  box.hidden = !(down || streamError);
  $("view").classList.toggle("down", !box.hidden);
  document.body.dataset.connection = down ? "disconnected" : streamError ? "error" : "live";
  document.body.dataset.errorSource = !down && streamError ? state.error_source || "other" : "";
  box.querySelector(".disconnected-title").textContent = down ? "Disconnected" : ERROR_TITLES[state.error_source] || "Error";
  $("disconnected-reason").textContent = reason;
}
$("reconnect").addEventListener("click", async () => {
  if (socket && socket.readyState === WebSocket.OPEN) {  // the server is there: the device failed, try it again
    const button = $("reconnect");
    const response = await fetch("/api/reconnect", { method: "POST", headers: { "Content-Type": "application/json", "X-Msflash-Token": token }, body: "{}" }).catch(() => null);
    const reply = response ? await response.json().catch(() => ({})) : {};
    button.dataset.tries = Number(button.dataset.tries || 0) + 1;
    button.dataset.result = response && response.ok ? "ok" : "failed";  // the reason stays the state's (pushed too)
    if (response && response.ok) render(reply);
    else $("disconnected-reason").textContent = reply.error || "the server does not answer";
    return;
  }
  if (socket) socket.onclose = null;
  if (socket) socket.close();
  connect();
});

// The flash before it fires: sliders for the mix, presets, Fire with exactly the mix shown.
function renderMix(mix) {
  $("mix-empty").hidden = !!mix;
  $("mix-body").hidden = !mix;
  $("flash-preview").dataset.run = mix ? mix.run : "";
  if (!mix) return;
  $("mix-run").textContent = `from ${mix.run}`;
  if (mix.run !== shownRun && (!state || state.job.status !== "running")) showRun(mix.run);
  const box = $("mix-leds");
  if (box.dataset.run !== mix.run) {
    box.dataset.run = mix.run;
    box.textContent = "";
    mix.led_names.forEach((name, i) => {
      const row = document.createElement("div");
      row.className = "led";
      row.innerHTML = `<span>${name}</span><input type="range" min="0" max="1000" step="1" id="mix-${i}">
        <output id="mix-${i}-value"></output><span></span>`;
      box.appendChild(row);
      row.querySelector("input").addEventListener("input", () => { mixLevels[i] = Number($(`mix-${i}`).value) / 1000; sendMix({ levels: mixLevels.slice() }); showMixLevels(); });
    });
    ["matching", "complementary"].forEach((mode) => { $(`mix-${mode}`).disabled = !(mode in mix.solved); });
  }
  if (!mixPosting && !mixPending) { mixLevels = mix.levels.slice(); showMixLevels(); }
  const capture = mix.capture;
  const caption = $("mix-capture-caption");
  if (capture) {
    caption.textContent = `captured: ${(100 * capture.relative_rms_difference).toFixed(1)} % RMS from the synthesis` + (capture.warning ? ` (${capture.warning})` : "");
    caption.dataset.difference = capture.relative_rms_difference;
  }
}
function showMixLevels() {
  mixLevels.forEach((level, i) => {
    setIfIdle($(`mix-${i}`), Math.round(level * 1000));
    $(`mix-${i}-value`).textContent = (level * 100).toFixed(1) + "%";
  });
}
async function sendMix(body) {
  mixPending = body;
  if (mixPosting) return;
  while (mixPending) {
    const next = mixPending;
    mixPending = null;
    mixPosting = true;
    const reply = await post("/api/mix", next);
    mixPosting = false;
    if (reply && reply.mix && !mixPending) { mixLevels = reply.mix.levels.slice(); showMixLevels(); }
  }
}
$("mix-matching").addEventListener("click", () => sendMix({ preset: "matching" }));
$("mix-complementary").addEventListener("click", () => sendMix({ preset: "complementary" }));
$("mix-ambient-only").addEventListener("click", () => sendMix({ preset: "ambient" }));
$("mix-fire").addEventListener("click", async () => {
  $("mix-fire").disabled = true;
  while (mixPosting || mixPending) await new Promise((resolve) => setTimeout(resolve, 20));  // the mix shown is sent
  const reply = await post("/api/mix-fire", { levels: mixLevels });
  $("mix-fire").disabled = false;
  if (reply && reply.mix) renderMix(reply.mix);
});

// Keyboard: space fires the sequence, z zooms, s takes a snapshot, o switches the LEDs off.
document.addEventListener("keydown", (event) => {
  const tag = event.target && event.target.tagName;
  if (tag === "INPUT" && event.target.type !== "range" || tag === "SELECT" || tag === "TEXTAREA") return;
  if (event.ctrlKey || event.metaKey || event.altKey) return;
  const actions = { " ": () => { if (!$("fire").disabled) $("fire").click(); }, z: toggleZoom, s: snapshot, o: () => post("/api/leds-off") };
  const action = actions[event.key];
  if (!action) return;
  event.preventDefault();
  action();
});

function connect() {
  const ws = new WebSocket(`ws://${location.host}/ws?token=${encodeURIComponent(token)}`);
  socket = ws;
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { closedReason = ""; $("connection").textContent = "live"; $("connection").className = "badge on"; showDisconnected(); };
  ws.onmessage = (event) => {
    if (typeof event.data === "string") {
      const message = JSON.parse(event.data);
      if (message.type === "state") render(message.state);
    } else {
      onFrame(event.data);
    }
  };
  ws.onclose = (event) => {
    if (socket !== ws) return;
    const since = new Date().toLocaleTimeString();
    if (event.reason) closedReason = `the server closed the connection: ${event.reason} (${since}); retrying every 2 s`;
    else if (!closedReason) closedReason = `the server does not answer (stopped, or the network is down; ${since}); retrying every 2 s`;
    else closedReason = closedReason.replace(/; no answer since .*$/, "") + `; no answer since ${since}`;
    liveArrivals.length = 0;
    $("fps").textContent = "–";
    $("fps").dataset.fps = 0;
    $("connection").textContent = "disconnected";
    $("connection").className = "badge off";
    showDisconnected();
    setTimeout(() => { if (socket === ws) connect(); }, 2000);
  };
}

$("exposure").addEventListener("input", () => {
  $("exposure-value").textContent = formatUs(sliderToExposure(Number($("exposure").value)));
});
$("exposure").addEventListener("change", () => post("/api/settings", { exposure_us: sliderToExposure(Number($("exposure").value)) }));
$("gain").addEventListener("change", () => post("/api/settings", { gain: Number($("gain").value) }));
$("overlay").addEventListener("change", () => post("/api/settings", { overlay: $("overlay").checked }));
$("sequence-exposure").addEventListener("change", () => post("/api/settings", { sequence_exposure: $("sequence-exposure").value }));
$("mode").addEventListener("change", () => post("/api/settings", { mode: $("mode").value }));
$("leds-off").addEventListener("click", () => post("/api/leds-off"));
$("fire").addEventListener("click", async () => {
  $("fire").disabled = true;
  await post("/api/sequence", { mode: $("mode").value });
});

fetch("/api/state", { headers: { "X-Msflash-Token": token } }).then((r) => r.json()).then(render);
connect();
