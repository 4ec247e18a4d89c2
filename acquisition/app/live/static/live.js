// msflash live: draws what the server says (GET /api/state, pushed on the WebSocket) and sends every
// change as a POST carrying the session token. The page keeps no state of its own: a reload loses nothing.
"use strict";
const token = document.querySelector('meta[name="msflash-token"]').content;
const $ = (id) => document.getElementById(id);
let state = null;
let shownRun = null;
let frameUrl = null;
const EXPOSURE_STEPS = 1000;

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
  $("gain-value").textContent = state.gain.toFixed(1) + "×";
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
}

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
  const response = await fetch(`/api/runs/${encodeURIComponent(name)}`, { headers: { "X-Msflash-Token": token } });
  if (!response.ok) return;
  const run = await response.json();
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

function onFrame(buffer) {
  const view = new DataView(buffer);
  const length = view.getUint32(0, true);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, length)));
  const blob = new Blob([new Uint8Array(buffer, 4 + length)], { type: "image/jpeg" });
  const url = URL.createObjectURL(blob);
  const img = $("live");
  img.onload = () => { if (frameUrl && frameUrl !== url) URL.revokeObjectURL(frameUrl); frameUrl = url; };
  img.src = url;
  const count = $("frame-count");
  count.textContent = header.n;
  count.dataset.frames = header.n;
  $("frame-source").textContent = header.source;
  $("saturated").textContent = (100 * header.saturated).toFixed(2) + "%";
  drawHistogram(header.histogram);
  showBooth(header.booth_levels);
}

function connect() {
  const ws = new WebSocket(`ws://${location.host}/ws?token=${encodeURIComponent(token)}`);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { $("connection").textContent = "live"; $("connection").className = "badge on"; };
  ws.onmessage = (event) => {
    if (typeof event.data === "string") {
      const message = JSON.parse(event.data);
      if (message.type === "state") render(message.state);
    } else {
      onFrame(event.data);
    }
  };
  ws.onclose = () => {
    $("connection").textContent = "reconnecting…";
    $("connection").className = "badge";
    setTimeout(connect, 1000);
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
