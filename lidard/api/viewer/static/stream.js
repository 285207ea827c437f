// Streams in the web viewer: the frames of a running or finished stream, one cloud at a time.
//
// A running stream: the newest finished frame is shown as soon as GET /streams/{id} lists it (its
// points from GET /streams/{id}/frames/{k}/live). A finished (done or stopped) stream: its frames are
// played in a loop at the stream's own frame rate (the hardware rate of its first triggers), capped at
// PLAY_MAX_HZ for the eye. The counter says "frame k+1 / n" and the rate; window.viewer carries
// streamId, frameIndex, framesShown (frames drawn so far), frameRateHz and streamState for the tests.

const POLL_MS = 200;          // how often a running stream's status is asked for
const PLAY_MAX_HZ = 10;       // replay of a finished stream: at most this many frames per second

// The stream's hardware frame rate: frames started per second of the stream's own clock.
export function frameRateHz(frames) {
  if (frames.length < 2) return null;
  const a = frames[0], b = frames[frames.length - 1];
  const span = b.start_s - a.start_s;
  return span > 0 ? (frames.length - 1) / span : null;
}

export class StreamPlayer {
  constructor(viewer, api, els) {
    this.viewer = viewer; this.api = api; this.els = els;
    this.timer = null; this.busy = false; this.frames = []; this.state = null;
  }

  show(id) {
    this.stop();
    const v = this.viewer;
    v.streamId = id; v.frameIndex = null; v.framesShown = 0; v.frameRateHz = null; v.streamState = null;
    this.frames = []; this.state = null; this.nextPlay = 0;
    this.els.label.textContent = `stream ${id}`;
    this.els.counter.textContent = "waiting for the first frame";
    this.timer = setInterval(() => this.tick(), POLL_MS);
    this.tick();
  }

  stop() {
    if (this.timer !== null) clearInterval(this.timer);
    this.timer = null;
    this.viewer.streamId = null;
    this.els.counter.textContent = "";
  }

  async tick() {
    if (this.busy) return;
    this.busy = true;
    const id = this.viewer.streamId;
    try {
      const live = this.state === null || this.state === "running" || this.state === "queued";
      if (live) {
        const s = await (await this.api(`/streams/${id}`)).json();
        if (id !== this.viewer.streamId) return;
        this.frames = s.frames; this.state = s.state;
        this.viewer.streamState = s.state; this.viewer.frameRateHz = frameRateHz(s.frames);
      }
      const n = this.frames.length;
      if (!n) return;
      const running = this.state === "running" || this.state === "queued";
      let k;
      if (running) {
        k = n - 1;                                   // the newest finished frame
        if (k === this.viewer.frameIndex) return;
      } else {                                       // replay at the stream's rate
        const now = performance.now();
        if (now < this.nextPlay) return;
        const hz = Math.min(this.viewer.frameRateHz || PLAY_MAX_HZ, PLAY_MAX_HZ);
        this.nextPlay = now + 1000 / hz;
        k = this.viewer.frameIndex === null ? 0 : (this.viewer.frameIndex + 1) % n;
      }
      await this.draw(id, k, n);
    } catch (e) {
      this.viewer.lastError = String(e);
    } finally {
      this.busy = false;
    }
  }

  async draw(id, k, n) {
    const r = await this.api(`/streams/${id}/frames/${k}/live`);
    const rows = new Float32Array(await r.arrayBuffer());
    if (id !== this.viewer.streamId) return;
    const v = this.viewer;
    v.cloud.clear();
    v.cloud.append(rows);
    v.pointCount = v.cloud.count; v.complete = true;
    v.frameIndex = k; v.framesShown += 1;
    const rate = v.frameRateHz === null ? "rate …" : `${v.frameRateHz.toFixed(1)} Hz`;
    const side = this.frames[k] || {};
    this.els.counter.textContent = `frame ${k + 1} / ${n} · ${rate}` + (side.partial ? " (partial)" : "");
    this.els.points.textContent = `${v.pointCount} points`;
    this.els.onDrawn();
  }
}

// The streams list: one line per stream, a link shows it.
export function renderStreams(ul, streams, { onShow, shownId }) {
  ul.replaceChildren();
  for (const s of streams) {
    const li = document.createElement("li");
    li.dataset.stream = s.id;
    if (s.id === shownId) li.className = "ok";
    const a = document.createElement("a");
    a.href = "#"; a.textContent = s.id.slice(-8);
    a.onclick = (e) => { e.preventDefault(); onShow(s.id); };
    li.append(a, ` ${s.pattern} ${s.state} ${s.frames_done} frames`);
    ul.append(li);
  }
  if (!streams.length) ul.append(Object.assign(document.createElement("li"), { textContent: "none" }));
}
