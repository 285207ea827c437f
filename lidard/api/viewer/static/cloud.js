// The WebGL point cloud: a growing BufferGeometry, colour maps, orbit/zoom and a pixel picker.
// Points arrive as float32 rows in the field order of GET /scans/{id}/points/live (X-Lidard-Fields).
import * as THREE from "three";
import { OrbitControls } from "/viewer/vendor/OrbitControls.js";

// Turbo-like ramp (sequential) and a blue-white-red ramp (signed velocity), as [t, r, g, b] stops.
const RAMP = [[0, .19, .07, .23], [.25, .16, .64, .97], [.5, .44, .99, .35], [.75, .98, .62, .13], [1, .48, .02, .01]];
const DIVERGING = [[0, .23, .3, .9], [.5, .92, .92, .92], [1, .85, .15, .12]];

function ramp(stops, t) {
  t = Math.min(1, Math.max(0, Number.isFinite(t) ? t : 0));
  for (let i = 1; i < stops.length; i++) {
    if (t <= stops[i][0]) {
      const a = stops[i - 1], b = stops[i], u = (t - a[0]) / (b[0] - a[0]);
      return [a[1] + u * (b[1] - a[1]), a[2] + u * (b[2] - a[2]), a[3] + u * (b[3] - a[3])];
    }
  }
  return stops[stops.length - 1].slice(1);
}

// The colour of a value ``t`` in 0..1 in the map of ``mode`` (the colour bar draws the same map).
export function colorOf(mode, t) { return ramp(mode === "velocity" ? DIVERGING : RAMP, t); }

export class Cloud {
  constructor(canvas, fields) {
    this.canvas = canvas;
    this.fields = fields;
    this.stride = fields.length;
    this.data = new Float32Array(0);   // every point so far, stride floats each
    this.count = 0;
    this.mode = "range";
    this.userMoved = false;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(1);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
    // the sensor looks along +z; view from behind it, y up
    this.camera.position.set(0, 0, -0.6);
    this.camera.up.set(0, 1, 0);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.target.set(0, 0, 1);
    this.controls.addEventListener("start", () => { this.userMoved = true; });
    this.geometry = new THREE.BufferGeometry();
    this.material = new THREE.PointsMaterial({ size: 4, sizeAttenuation: false, vertexColors: true });
    this.points = new THREE.Points(this.geometry, this.material);
    this.points.scale.x = -1;  // the sensor frame's +x is to the left seen from behind it (optics.directions)
    this.scene.add(this.points);
    this._alloc(4096);
    canvas.addEventListener("click", (ev) => this.onPick && this.onPick(this.pick(ev)));
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
    const loop = () => { this.controls.update(); this.renderer.render(this.scene, this.camera); requestAnimationFrame(loop); };
    loop();
  }

  _alloc(capacity) {
    const pos = new Float32Array(capacity * 3), col = new Float32Array(capacity * 3);
    if (this.geometry.attributes.position) {
      pos.set(this.geometry.attributes.position.array.subarray(0, this.count * 3));
      col.set(this.geometry.attributes.color.array.subarray(0, this.count * 3));
    }
    this.capacity = capacity;
    this.geometry.setAttribute("position", new THREE.BufferAttribute(pos, 3));
    this.geometry.setAttribute("color", new THREE.BufferAttribute(col, 3));
    this.geometry.setDrawRange(0, this.count);
  }

  resize() {
    const w = this.canvas.clientWidth || 1, h = this.canvas.clientHeight || 1;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
  }

  clear() {
    this.data = new Float32Array(0);
    this.count = 0;
    this.userMoved = false;
    this.geometry.setDrawRange(0, 0);
  }

  append(rows) {   // rows: Float32Array, a multiple of stride
    const n = rows.length / this.stride;
    if (!n) return;
    const merged = new Float32Array(this.data.length + rows.length);
    merged.set(this.data); merged.set(rows, this.data.length);
    this.data = merged;
    if (this.count + n > this.capacity) this._alloc(Math.max(this.capacity * 2, this.count + n));
    const pos = this.geometry.attributes.position.array;
    const ix = this.fields.indexOf("x");
    for (let i = 0; i < n; i++) {
      const r = i * this.stride, o = (this.count + i) * 3;
      pos[o] = rows[r + ix]; pos[o + 1] = rows[r + ix + 1]; pos[o + 2] = rows[r + ix + 2];
    }
    this.count += n;
    this.geometry.attributes.position.needsUpdate = true;
    this.geometry.setDrawRange(0, this.count);
    // about one beam step per point on screen when the cloud fills the view
    this.material.size = Math.min(12, Math.max(2, 0.8 * this.canvas.clientHeight / Math.sqrt(this.count)));
    this.bounds = this._bounds();
    this.geometry.boundingSphere = this.bounds.getBoundingSphere(new THREE.Sphere());
    this.recolor();
    if (!this.userMoved) this.fit();
  }

  column(name) {
    const k = this.fields.indexOf(name), out = new Float32Array(this.count);
    for (let i = 0; i < this.count; i++) out[i] = this.data[i * this.stride + k];
    return out;
  }

  // Colour limits: 2nd..98th percentile, so one outlier does not wash out the map; velocity symmetric.
  limits(values) {
    if (!values.length) return [0, 1];
    const s = Float32Array.from(values).sort();
    let lo = s[Math.floor(0.02 * (s.length - 1))], hi = s[Math.ceil(0.98 * (s.length - 1))];
    if (this.mode === "velocity") { const m = Math.max(Math.abs(lo), Math.abs(hi), 1e-3); lo = -m; hi = m; }
    if (hi <= lo) hi = lo + 1e-6;
    return [lo, hi];
  }

  recolor() {
    const v = this.column(this.mode), [lo, hi] = this.limits(v);
    const stops = this.mode === "velocity" ? DIVERGING : RAMP;
    const col = this.geometry.attributes.color.array;
    for (let i = 0; i < this.count; i++) col.set(ramp(stops, (v[i] - lo) / (hi - lo)), i * 3);
    this.geometry.attributes.color.needsUpdate = true;
    this.colorLimits = [lo, hi];
  }

  setMode(mode) { this.mode = mode; this.recolor(); }

  // Box of the bulk of the points (1st..99th percentile per axis), so a stray return far off does not
  // shrink the letters to a dot; the buffer beyond ``count`` is spare capacity and not looked at.
  _bounds() {
    const lo = new THREE.Vector3(), hi = new THREE.Vector3();
    ["x", "y", "z"].forEach((f, k) => {
      const s = this.column(f).sort(), n = s.length - 1;
      lo.setComponent(k, s[Math.floor(0.01 * n)]); hi.setComponent(k, s[Math.ceil(0.99 * n)]);
    });
    return new THREE.Box3(lo, hi);
  }

  // Look at the cloud from the sensor's place (the view the scanner has, as in Fig. 4-35), with the
  // field of view narrowed to frame the points; orbiting starts from there.
  fit() {
    if (!this.count) return;
    const box = this.bounds, c = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3());
    c.x *= this.points.scale.x;
    this.controls.target.copy(c);
    const dist = Math.max(c.z, 2 * size.z, 0.1);
    const half = Math.max(size.y / 2, size.x / 2 / this.camera.aspect, 0.002) * 1.15;
    const fov = 2 * THREE.MathUtils.radToDeg(Math.atan(half / Math.max(dist - size.z / 2, 0.01)));
    this.camera.fov = Math.min(60, Math.max(0.5, fov));
    this.camera.position.set(c.x, c.y, c.z - dist);
    this.camera.near = dist / 100; this.camera.far = dist * 100;
    this.camera.updateProjectionMatrix();
  }

  // Where point ``i`` is drawn, in client (page) pixels.
  screenOf(i) {
    const rect = this.canvas.getBoundingClientRect(), pos = this.geometry.attributes.position.array;
    this.points.updateMatrixWorld();
    const v = new THREE.Vector3(pos[i * 3], pos[i * 3 + 1], pos[i * 3 + 2]).applyMatrix4(this.points.matrixWorld).project(this.camera);
    return { x: rect.left + (v.x + 1) / 2 * rect.width, y: rect.top + (1 - v.y) / 2 * rect.height };
  }

  // Nearest point to the click on screen (within 10 px): its fields, or null.
  pick(ev) {
    const rect = this.canvas.getBoundingClientRect();
    const mx = ev.clientX - rect.left, my = ev.clientY - rect.top;
    const pos = this.geometry.attributes.position.array, v = new THREE.Vector3();
    this.points.updateMatrixWorld();
    let best = -1, bestD = 100;
    for (let i = 0; i < this.count; i++) {
      v.set(pos[i * 3], pos[i * 3 + 1], pos[i * 3 + 2]).applyMatrix4(this.points.matrixWorld).project(this.camera);
      if (v.z > 1) continue;
      const sx = (v.x + 1) / 2 * rect.width, sy = (1 - v.y) / 2 * rect.height;
      const d = (sx - mx) ** 2 + (sy - my) ** 2;
      if (d < bestD) { bestD = d; best = i; }
    }
    if (best < 0) return null;
    const out = { index: best };
    this.fields.forEach((f, k) => { out[f] = this.data[best * this.stride + k]; });
    return out;
  }

  // Mean and variance of the rendered canvas's luminance (the browser test checks it is not blank).
  pixelStats() {
    const gl = this.renderer.getContext(), w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    const px = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
    let s = 0, s2 = 0, lit = 0;
    for (let i = 0; i < px.length; i += 4) {
      const l = (px[i] + px[i + 1] + px[i + 2]) / 3;
      s += l; s2 += l * l; if (l > 20) lit++;
    }
    const n = w * h, mean = s / n;
    return { mean, variance: s2 / n - mean * mean, lit };
  }
}
