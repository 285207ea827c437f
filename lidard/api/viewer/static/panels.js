// The side panels: scan queue (progress, ETA, cancel), devices, bench faults, calibrations and the
// linearization convergence plot. Pure rendering from API JSON; viewer.js does the fetching.

function el(tag, attrs = {}, ...kids) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k.startsWith("on")) e.addEventListener(k.slice(2), v); else e.setAttribute(k, v);
  }
  for (const k of kids) e.append(k);
  return e;
}

export function fmtDuration(s) {
  if (!Number.isFinite(s) || s < 0) return "–";
  if (s < 60) return `${s.toFixed(0)} s`;
  return `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`;
}

// Remaining wall time of a running scan: the fraction to go at the rate seen since this page first saw
// the scan scanning with pixels done (its start time would count the linearization and set-up too).
const firstSeen = new Map();
export function eta(scan, nowS) {
  const f = scan.progress;
  if (scan.state !== "running" || !(f > 0) || (scan.stage && scan.stage !== "scanning")) return NaN;
  const first = firstSeen.get(scan.id);
  if (!first) { firstSeen.set(scan.id, { t: nowS, f }); return NaN; }
  if (!(f > first.f) || !(nowS > first.t)) return NaN;
  return (nowS - first.t) * (1 - f) / (f - first.f);
}

export function renderQueue(ul, scans, { canAct, onCancel, onShow, shownId }) {
  ul.replaceChildren();
  for (const s of scans) {
    const live = s.state === "running" || s.state === "queued";
    const li = el("li", { "data-scan": s.id, class: s.id === shownId ? "ok" : "" },
      el("a", { href: "#", onclick: (e) => { e.preventDefault(); onShow(s.id); } }, s.id.slice(-8)),
      ` ${s.request.pattern} ${s.state} `);
    if (s.state === "running") {
      li.append(el("progress", { max: "1", value: String(s.progress) }),
        ` ${(100 * s.progress).toFixed(0)} % ETA ${fmtDuration(eta(s, Date.now() / 1000))}`);
    } else if (s.state === "done" || s.partial) {
      li.append(` ${s.counts.points} pts`);
    }
    if (s.error) li.append(el("span", { class: "bad", title: s.error }, " ⚠"));
    if (live && canAct) li.append(" ", el("button", { onclick: () => onCancel(s.id) }, "cancel"));
    ul.append(li);
  }
}

// One line per device: its link, its status (GET /devices answers it as data and as a line) and,
// on hover, its identity. ``busy``: a job holds the instrument, the line is the last check.
export function renderDevices(ul, devices) {
  ul.replaceChildren();
  for (const d of devices) {
    const cls = d.connected === false ? "bad" : (d.faults && d.faults.length ? "warn" : "ok");
    const state = d.connected === false ? "offline" : (d.state || "connected");
    ul.append(el("li", { class: cls, title: d.identity || "" }, `${d.name}: ${state}`,
      d.faults && d.faults.length ? ` (faults: ${d.faults.join("; ")})` : "",
      d.busy ? el("span", { class: "note" }, " busy: last check") : ""));
  }
}

// Why some FPSA rows have no points: they are not bonded to the HV driver (§4.3.3), so no beam
// leaves them and the image has a dark stripe there. The fpsa's identity lists its bonded rows.
export function unbondedRows(scanner, devices) {
  const [rows] = scanner.pixels || [0];
  const ident = (devices.find((d) => d.name === "fpsa") || {}).identity_fields || {};
  if (Array.isArray(ident.bonded_rows)) {
    const bonded = new Set(ident.bonded_rows), out = [];
    for (let r = 0; r < rows; r++) if (!bonded.has(r)) out.push(r);
    return out;
  }
  return null;
}

export function rowsNote(scanner, unbonded) {
  const [rows] = scanner.pixels || [0], bonded = scanner.bonded_rows ?? rows;
  if (bonded >= rows) return "";
  const list = unbonded && unbonded.length ? ` (rows ${unbonded.slice(0, 4).join(", ")}${unbonded.length > 4 ? ", …" : ""})` : "";
  return `Dark stripes: ${rows - bonded} of ${rows} FPSA rows are not bonded to the switch driver${list}; ` +
    "no beam leaves them, so they have no points (§4.3.3).";
}

export function renderFaults(ul, faults, simulated) {
  ul.replaceChildren();
  if (!simulated) { ul.append(el("li", {}, "real hardware: no injected faults")); return; }
  if (!faults.length) { ul.append(el("li", { class: "ok" }, "none active")); return; }
  for (const f of faults) {
    const { id, kind, ...rest } = f;
    ul.append(el("li", { class: "warn" }, `${kind} ${JSON.stringify(rest)}`));
  }
}

// The last scan's linearization check (GET /health ``linearization``) in one line.
export function linearizationLine(lin) {
  if (!lin) return "chirp check: none yet (made before each scan)";
  if (lin.residual_hz == null) return `chirp re-linearized (${lin.reason}), not checked`;
  return `chirp error ${(lin.residual_hz / 1e3).toFixed(0)} kHz rms (threshold ${(lin.threshold_hz / 1e3).toFixed(0)} kHz)` +
    (lin.relinearized ? `; re-linearized: ${lin.reason}` : "");
}

export function renderCalibrations(ul, cals) {
  ul.replaceChildren();
  if (!cals.length) { ul.append(el("li", {}, "no linearization yet: the first scan or `lidarctl linearize` makes one")); return; }
  for (const c of cals) {
    const when = c.created ? new Date(c.created * 1000).toLocaleTimeString() : "?";
    ul.append(el("li", { class: c.converged ? "ok" : "warn" },
      `${when} ${c.laser} ${c.temperature_c?.toFixed(2)} °C, ${c.iterations.length} it., ` +
      `up ÷${(c.reduction.up ?? NaN).toFixed(1)} down ÷${(c.reduction.down ?? NaN).toFixed(1)}`));
  }
}

// rms chirp-frequency error per ILC iteration (§2.2), log scale, up and down ramps; newest calibration
// bold, older ones faint.
export function plotConvergence(canvas, cals) {
  const g = canvas.getContext("2d"), W = canvas.width, H = canvas.height, m = 32;
  g.fillStyle = "#111"; g.fillRect(0, 0, W, H);
  const series = [];
  cals.forEach((c, ci) => ["up_rms_hz", "down_rms_hz"].forEach((k, ki) => {
    const ys = c.iterations.map((it) => it[k]).filter((v) => v > 0);
    if (ys.length) series.push({ ys, color: ki ? "#f96" : "#6cf", alpha: ci ? 0.25 : 1 });
  }));
  g.fillStyle = "#aaa"; g.font = "11px sans-serif";
  if (!series.length) { g.fillText("no linearization yet", m, H / 2); return; }
  const all = series.flatMap((s) => s.ys), n = Math.max(...series.map((s) => s.ys.length));
  const lo = Math.floor(Math.log10(Math.min(...all))), hi = Math.ceil(Math.log10(Math.max(...all)));
  const X = (i) => m + (W - m - 8) * (n > 1 ? i / (n - 1) : 0.5);
  const Y = (v) => H - 18 - (H - 26) * (Math.log10(v) - lo) / Math.max(hi - lo, 1);
  g.strokeStyle = "#444";
  for (let d = lo; d <= hi; d++) { g.beginPath(); g.moveTo(m, Y(10 ** d)); g.lineTo(W, Y(10 ** d)); g.stroke(); g.fillText(`1e${d}`, 2, Y(10 ** d) + 4); }
  g.fillText("iteration →   rms error (Hz): up (blue), down (orange)", m, H - 4);
  for (const s of series.reverse()) {
    g.globalAlpha = s.alpha; g.strokeStyle = s.color; g.lineWidth = s.alpha < 1 ? 1 : 2; g.beginPath();
    s.ys.forEach((v, i) => (i ? g.lineTo(X(i), Y(v)) : g.moveTo(X(i), Y(v))));
    g.stroke();
  }
  g.globalAlpha = 1;
}
