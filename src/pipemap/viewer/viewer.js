// The pipemap viewer: draws the data block that `pipemap report` wrote into this page.
// Coordinates follow docs/formats.md: a wall column is a distance along the pipe (chainage, or h from the
// piece's start in older results), a row a clock position (0 deg = 12 o'clock, clockwise looking along the
// survey); pixel coordinates have their origin at the centre of the top-left pixel.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

const DATA = JSON.parse(document.getElementById("pipemap-data").textContent);
const ROOT = document.documentElement;

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v; else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c instanceof Node ? c : String(c));
  return node;
}
const mod = (a, n) => ((a % n) + n) % n;
const fmt = (v, digits) => (v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(digits));

// ---- the inspector's coordinates (walls.py computes the same) ----
const alongOfCol = (w, col) => w.along0 + col * w.alongPx;
const clockOfRow = (w, row) => mod(w.phi0Deg + row * w.phiPerRowDeg, 360);
const rowsPerTurn = (w) => 360 / Math.abs(w.phiPerRowDeg);
const rowOfClock = (w, deg) => mod((deg - w.phi0Deg) / w.phiPerRowDeg, rowsPerTurn(w));
function clockText(deg) {
  const minutes = mod(Math.round(deg * 2), 720);
  const h = Math.floor(minutes / 60) || 12;
  return `${h}:${String(minutes % 60).padStart(2, "0")}`;
}
const alongName = (w) => (w.alongKind === "chainage" ? "chainage" : `h along ${w.name}`);

function base64Bytes(text) {
  const raw = atob(text);
  const out = new Uint8Array(raw.length);
  for (let i = 0; i < raw.length; i++) out[i] = raw.charCodeAt(i);
  return out;
}

// ---- header ----
function header() {
  document.getElementById("title").textContent = `pipemap viewer: ${DATA.title}`;
  const parts = [];
  if (DATA.method) parts.push(`method ${DATA.method}`);
  if (DATA.trajectory) parts.push(`${DATA.trajectory.length} keyframes`);
  if (DATA.junctions) parts.push(`${DATA.junctions.length} junctions`);
  parts.push(`${DATA.walls.length} unrolled walls`);
  if (DATA.cloud) parts.push(`appearance map: ${DATA.cloud.count.toLocaleString()} of ` +
    `${DATA.cloud.total.toLocaleString()} points drawn`);
  if (DATA.quality) parts.push(DATA.quality);
  document.getElementById("summary").textContent = parts.join(" · ");
  const list = document.getElementById("missing");
  for (const m of DATA.missing) list.append(el("li", {}, m));
}

// ---- 3D view ----
function vec(a) { return new THREE.Vector3(a[0], a[1], a[2]); }

function pieceAxis(p) {
  // The axis as h -> {at, tangent}: a straight piece's line, or an elbow's arc turning about its normal.
  const a = vec(p.start);
  if (p.kind !== "arc") {
    const b = vec(p.end), u = b.clone().sub(a).normalize();
    return { length: a.distanceTo(b), at: (h) => ({ at: a.clone().addScaledVector(u, h), tangent: u.clone() }) };
  }
  const c = vec(p.centre), n = vec(p.normal).normalize();
  const rho = a.distanceTo(c), e1 = a.clone().sub(c).normalize(), e2 = new THREE.Vector3().crossVectors(n, e1);
  const angle = THREE.MathUtils.degToRad(p.angle_deg);
  return {
    length: rho * angle,
    at: (h) => {
      const t = h / rho, cos = Math.cos(t), sin = Math.sin(t);
      return { at: c.clone().addScaledVector(e1, rho * cos).addScaledVector(e2, rho * sin),
        tangent: e1.clone().multiplyScalar(-sin).addScaledVector(e2, cos) };
    },
  };
}

function pipeOutline(p) {
  // Rings every 0.5 m (an elbow: every 15 deg at the most), four lines along the wall (12 o'clock red), the axis.
  const axis = pieceAxis(p);
  const length = axis.length;
  const at = (h, angle) => {
    const { at: x, tangent: u } = axis.at(h);
    const up = vec(p.up); up.addScaledVector(u, -up.dot(u)).normalize();
    const cw = new THREE.Vector3().crossVectors(u, up);
    return x.addScaledVector(up, p.radius * Math.cos(angle)).addScaledVector(cw, p.radius * Math.sin(angle));
  };
  const pos = [], col = [];
  const push = (x, y, c) => { pos.push(x.x, x.y, x.z, y.x, y.y, y.z); col.push(...c, ...c); };
  const arc = p.kind === "arc";
  const rings = Math.max(1, Math.round(length / 0.5), arc ? Math.ceil(p.angle_deg / 15) : 1);
  const steps = arc ? Math.max(8, Math.ceil(p.angle_deg / 3)) : 1;
  for (let i = 0; i <= rings; i++) {
    const h = (length * i) / rings;
    for (let k = 0; k < 24; k++) push(at(h, (k * Math.PI) / 12), at(h, ((k + 1) * Math.PI) / 12), [0.33, 0.47, 0.67]);
  }
  for (let i = 0; i < steps; i++) {
    const h0 = (length * i) / steps, h1 = (length * (i + 1)) / steps;
    for (let k = 0; k < 4; k++) push(at(h0, (k * Math.PI) / 2), at(h1, (k * Math.PI) / 2),
      k === 0 ? [1.0, 0.25, 0.25] : [0.33, 0.47, 0.67]);
    push(axis.at(h0).at, axis.at(h1).at, [0.6, 0.7, 1.0]);
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.Float32BufferAttribute(pos, 3));
  g.setAttribute("color", new THREE.Float32BufferAttribute(col, 3));
  const lines = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ vertexColors: true }));
  lines.name = `piece-${p.name}`;
  return lines;
}

function cloudPoints(cloud) {
  const xyz = new Float32Array(base64Bytes(cloud.xyz).buffer);
  const grey = base64Bytes(cloud.grey);
  const rgb = new Uint8Array(grey.length * 3);
  for (let i = 0; i < grey.length; i++) rgb[3 * i] = rgb[3 * i + 1] = rgb[3 * i + 2] = grey[i];
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.BufferAttribute(xyz, 3));
  g.setAttribute("color", new THREE.BufferAttribute(rgb, 3, true));
  return new THREE.Points(g, new THREE.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: true }));
}

const JUNCTION_COLOURS = { tee: 0x40c0ff, cross: 0xff80ff, elbow: 0x80ff80 };

function sceneContents(scene) {
  const groups = { cloud: new THREE.Group(), trajectory: new THREE.Group(), pipes: new THREE.Group() };
  Object.values(groups).forEach((g) => scene.add(g));
  const box = new THREE.Box3();
  if (DATA.cloud) groups.cloud.add(cloudPoints(DATA.cloud));
  if (DATA.trajectory && DATA.trajectory.length > 1) {
    const g = new THREE.BufferGeometry().setFromPoints(DATA.trajectory.map(vec));
    groups.trajectory.add(new THREE.Line(g, new THREE.LineBasicMaterial({ color: 0xffa040 })));
    DATA.trajectory.forEach((p) => box.expandByPoint(vec(p)));
  }
  for (const p of DATA.pieces) {
    groups.pipes.add(pipeOutline(p));
    box.expandByPoint(vec(p.start)); box.expandByPoint(vec(p.end));
    if (p.kind === "arc") { const axis = pieceAxis(p); box.expandByPoint(axis.at(axis.length / 2).at); }
  }
  const radius = DATA.radius || (DATA.pieces[0] && DATA.pieces[0].radius) || 0.1;
  const labels = [];
  for (const j of DATA.junctions || []) {
    const m = new THREE.Mesh(new THREE.SphereGeometry(radius * 0.35, 16, 12),
      new THREE.MeshBasicMaterial({ color: JUNCTION_COLOURS[j.type] || 0xffffff }));
    m.position.copy(vec(j.centroid));
    groups.pipes.add(m);
    box.expandByPoint(m.position);
    const text = j.chainage_m === undefined ? `${j.id} ${j.type}` : `${j.id} ${j.type} · ${fmt(j.chainage_m, 2)} m`;
    labels.push({ at: m.position.clone(), node: el("div", { class: "label3d" }, text) });
  }
  for (const o of (DATA.observations && DATA.observations.rows) || []) {
    if (o.x === null || o.x === undefined || o.y === null || o.z === null) continue;
    const m = new THREE.Mesh(new THREE.SphereGeometry(radius * 0.12, 10, 8),
      new THREE.MeshBasicMaterial({ color: 0xff3030 }));
    m.position.set(o.x, o.y, o.z);
    groups.pipes.add(m);
  }
  if (box.isEmpty() && DATA.cloud) box.setFromObject(groups.cloud);
  if (box.isEmpty()) box.set(new THREE.Vector3(-1, -1, -1), new THREE.Vector3(1, 1, 1));
  return { groups, labels, box };
}

function build3d() {
  const canvas = document.getElementById("canvas3d");
  const holder = document.getElementById("view3d");
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0x1c1f24);
  const { groups, labels, box } = sceneContents(scene);
  const layer = document.getElementById("labels3d");
  labels.forEach((l) => layer.append(l.node));

  const centre = box.getCenter(new THREE.Vector3());
  const size = Math.max(box.getSize(new THREE.Vector3()).length(), 0.5);
  const up = vec(DATA.up).normalize();
  const across = Math.abs(up.x) < 0.9 ? new THREE.Vector3(1, 0, 0) : new THREE.Vector3(0, 1, 0);
  across.addScaledVector(up, -across.dot(up)).normalize();
  const camera = new THREE.PerspectiveCamera(45, 1, size / 1000, size * 20);
  camera.up.copy(up);
  const distance = (0.5 * size) / Math.tan(THREE.MathUtils.degToRad(camera.fov / 2));
  camera.position.copy(centre).addScaledVector(up, distance * 0.85).addScaledVector(across, distance * 0.5);
  const controls = new OrbitControls(camera, canvas);
  controls.target.copy(centre);
  controls.update();

  const projected = new THREE.Vector3();
  const render = () => {
    renderer.render(scene, camera);
    const w = canvas.clientWidth, h = canvas.clientHeight;
    const show = document.getElementById("show-labels").checked;
    for (const l of labels) {
      projected.copy(l.at).project(camera);
      const visible = show && projected.z < 1 && Math.abs(projected.x) < 1 && Math.abs(projected.y) < 1;
      l.node.style.display = visible ? "" : "none";
      l.node.style.left = `${((projected.x + 1) / 2) * w}px`;
      l.node.style.top = `${((1 - projected.y) / 2) * h}px`;
    }
  };
  const resize = () => {
    const w = holder.clientWidth, h = holder.clientHeight;
    renderer.setSize(w, h, false);
    camera.aspect = w / Math.max(h, 1);
    camera.updateProjectionMatrix();
    render();
  };
  controls.addEventListener("change", render);
  for (const [id, group] of [["show-cloud", groups.cloud], ["show-trajectory", groups.trajectory],
    ["show-pipes", groups.pipes]]) {
    document.getElementById(id).addEventListener("change", (e) => { group.visible = e.target.checked; render(); });
  }
  document.getElementById("show-labels").addEventListener("change", render);
  new ResizeObserver(resize).observe(holder);
  resize();
  const outlines = DATA.pieces.map((p) => {
    // each outline's name and the middle of its axis, for checks against the exact geometry
    const axis = pieceAxis(p), mid = axis.at(axis.length / 2).at;
    return `${p.name}:${p.kind || "line"}:${[mid.x, mid.y, mid.z].map((v) => v.toFixed(4)).join(":")}`;
  });
  return { drawnPixels: () => drawnPixels(renderer, scene, camera), outlines };
}

function drawnPixels(renderer, scene, camera) {
  // Read back right after a render (the drawing buffer is not preserved between frames).
  renderer.render(scene, camera);
  const gl = renderer.getContext();
  const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
  const px = new Uint8Array(w * h * 4);
  gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
  let count = 0;
  for (let i = 0; i < px.length; i += 4) {
    if (Math.abs(px[i] - 0x1c) + Math.abs(px[i + 1] - 0x1f) + Math.abs(px[i + 2] - 0x24) > 24) count++;
  }
  return count;
}

// ---- unrolled walls ----
const MARGIN = { left: 30, right: 6, top: 4, bottom: 22 };
const MAX_WALL_HEIGHT = 300;
const TICK_STEPS = [0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100];
const CLOCK_LINES = [[0, "12"], [90, "3"], [180, "6"], [270, "9"]];
// The rows a clock position falls on: once, or twice where the image covers the whole turn and it falls on the
// first row (12 o'clock at the top edge is also the bottom edge).
const clockRows = (w, deg) => [rowOfClock(w, deg), rowOfClock(w, deg) + rowsPerTurn(w)].filter((r) => r <= w.rows);

class WallView {
  constructor(wall, image, holder) {
    this.w = wall;
    this.image = image;
    this.markers = [];
    this.pick = null;
    const last = alongOfCol(wall, wall.cols - 1);
    const range = `${alongName(wall)} ${fmt(wall.along0, 2)} to ${fmt(last, 2)} m · ${wall.cols} × ${wall.rows} px`;
    this.canvas = el("canvas", { "data-wall": wall.name });
    this.readout = el("div", { class: "readout" });
    this.node = el("div", { class: "wall", id: `wall-${wall.name}` }, el("h3", {}, `${wall.name}: ${range}`),
      this.canvas, this.readout);
    holder.append(this.node);
    this.listen();
  }

  layout() {
    const cssW = Math.max(this.canvas.clientWidth, 200);
    this.plotW = cssW - MARGIN.left - MARGIN.right;
    this.fitScale = Math.min(this.plotW / this.w.cols, MAX_WALL_HEIGHT / this.w.rows);
    this.plotH = Math.max(60, Math.round(this.w.rows * this.fitScale));
    const cssH = this.plotH + MARGIN.top + MARGIN.bottom;
    const dpr = window.devicePixelRatio || 1;
    this.canvas.style.height = `${cssH}px`;
    this.canvas.width = Math.round(cssW * dpr);
    this.canvas.height = Math.round(cssH * dpr);
    this.dpr = dpr;
    if (this.scale === undefined) this.fit();
  }

  fit() {
    this.scale = this.fitScale;
    this.ox = Math.max(0, (this.plotW - this.w.cols * this.scale) / 2);
    this.oy = 0;
  }

  toImage(x, y) {
    return [(x - MARGIN.left - this.ox) / this.scale - 0.5, (y - MARGIN.top - this.oy) / this.scale - 0.5];
  }

  toCanvas(col, row) {
    return [MARGIN.left + this.ox + (col + 0.5) * this.scale, MARGIN.top + this.oy + (row + 0.5) * this.scale];
  }

  draw() {
    const ctx = this.canvas.getContext("2d");
    const w = this.w;
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    ctx.fillStyle = "#fff";
    ctx.fillRect(0, 0, this.canvas.width, this.canvas.height);
    ctx.save();
    ctx.beginPath();
    ctx.rect(MARGIN.left, MARGIN.top, this.plotW, this.plotH);
    ctx.clip();
    ctx.fillStyle = "#3a3d42";
    ctx.fillRect(MARGIN.left, MARGIN.top, this.plotW, this.plotH);
    ctx.imageSmoothingEnabled = this.scale < 2;
    ctx.drawImage(this.image, MARGIN.left + this.ox, MARGIN.top + this.oy, w.cols * this.scale, w.rows * this.scale);
    this.drawGrid(ctx);
    this.drawMarkers(ctx);
    ctx.restore();
    this.drawLabels(ctx);
  }

  tickStep() {
    return TICK_STEPS.find((s) => (s / this.w.alongPx) * this.scale >= 70) || TICK_STEPS[TICK_STEPS.length - 1];
  }

  drawGrid(ctx) {
    const w = this.w;
    ctx.lineWidth = 1;
    for (const [deg] of CLOCK_LINES) {
      for (const row of clockRows(w, deg)) {
        const y = this.toCanvas(0, row)[1];
        ctx.strokeStyle = deg === 0 ? "rgba(255,60,60,0.9)" : "rgba(120,200,255,0.75)";
        ctx.beginPath(); ctx.moveTo(MARGIN.left, y); ctx.lineTo(MARGIN.left + this.plotW, y); ctx.stroke();
      }
    }
    const step = this.tickStep();
    const first = Math.ceil(w.along0 / step) * step;
    const last = alongOfCol(w, w.cols - 1);
    for (let a = first; a <= last + 1e-9; a += step) {
      const x = this.toCanvas((a - w.along0) / w.alongPx, 0)[0];
      const metre = Math.abs(a - Math.round(a)) < 1e-6;
      ctx.strokeStyle = metre ? "rgba(255,220,60,0.85)" : "rgba(255,220,60,0.35)";
      ctx.beginPath(); ctx.moveTo(x, MARGIN.top); ctx.lineTo(x, MARGIN.top + this.plotH); ctx.stroke();
    }
  }

  drawMarkers(ctx) {
    const turn = rowsPerTurn(this.w);
    ctx.font = "11px sans-serif";
    for (const m of this.markers) {
      for (const shift of [-turn, 0, turn]) {
        const [x1, y1] = this.toCanvas(m.col, m.row + shift);
        const [x2, y2] = this.toCanvas(m.col2, m.row2 + shift);
        ctx.strokeStyle = "#ff3030"; ctx.lineWidth = 2;
        ctx.beginPath();
        if (Math.abs(x2 - x1) < 4 && Math.abs(y2 - y1) < 4) ctx.arc(x1, y1, 6, 0, 2 * Math.PI);
        else ctx.rect(Math.min(x1, x2), Math.min(y1, y2), Math.abs(x2 - x1), Math.abs(y2 - y1));
        ctx.stroke();
        ctx.fillStyle = "#ff5050";
        ctx.fillText(m.label, Math.min(x1, x2) + 8, Math.min(y1, y2) - 4);
      }
    }
    if (this.pick) {
      const [x, y] = this.toCanvas(this.pick[0], this.pick[1]);
      ctx.strokeStyle = "#0f0"; ctx.lineWidth = 1.5;
      ctx.beginPath(); ctx.moveTo(x - 8, y); ctx.lineTo(x + 8, y); ctx.moveTo(x, y - 8); ctx.lineTo(x, y + 8);
      ctx.stroke();
    }
  }

  drawLabels(ctx) {
    const w = this.w;
    ctx.fillStyle = "#333"; ctx.font = "11px sans-serif"; ctx.textBaseline = "middle"; ctx.textAlign = "right";
    for (const [deg, name] of CLOCK_LINES) {
      for (const row of clockRows(w, deg)) {
        const y = this.toCanvas(0, row)[1];
        if (y >= MARGIN.top - 1 && y <= MARGIN.top + this.plotH + 1) ctx.fillText(name, MARGIN.left - 4, y);
      }
    }
    ctx.textAlign = "center"; ctx.textBaseline = "top";
    const step = this.tickStep();
    const digits = step >= 1 ? 0 : step >= 0.1 ? 1 : 2;
    const first = Math.ceil(w.along0 / step) * step;
    for (let a = first; a <= alongOfCol(w, w.cols - 1) + 1e-9; a += step) {
      const x = this.toCanvas((a - w.along0) / w.alongPx, 0)[0];
      if (x >= MARGIN.left && x <= MARGIN.left + this.plotW) ctx.fillText(`${a.toFixed(digits)} m`, x, MARGIN.top + this.plotH + 4);
    }
  }

  cssPoint(e) {
    const r = this.canvas.getBoundingClientRect();
    return [e.clientX - r.left, e.clientY - r.top];
  }

  listen() {
    const c = this.canvas;
    c.addEventListener("wheel", (e) => {
      e.preventDefault();
      const [x, y] = this.cssPoint(e);
      const f = Math.exp(-e.deltaY * 0.0015);
      const scale = Math.min(16, Math.max(this.fitScale * 0.5, this.scale * f));
      const k = scale / this.scale;
      this.ox = x - MARGIN.left - (x - MARGIN.left - this.ox) * k;
      this.oy = y - MARGIN.top - (y - MARGIN.top - this.oy) * k;
      this.scale = scale;
      this.draw();
    }, { passive: false });
    c.addEventListener("pointerdown", (e) => {
      const start = [e.clientX, e.clientY], origin = [this.ox, this.oy];
      let moved = 0;
      const move = (m) => {
        moved = Math.max(moved, Math.hypot(m.clientX - start[0], m.clientY - start[1]));
        this.ox = origin[0] + m.clientX - start[0];
        this.oy = origin[1] + m.clientY - start[1];
        this.draw();
      };
      const up = (u) => {
        window.removeEventListener("pointermove", move);
        window.removeEventListener("pointerup", up);
        if (moved < 4) this.click(...this.cssPoint(u));
      };
      window.addEventListener("pointermove", move);
      window.addEventListener("pointerup", up);
    });
    c.addEventListener("dblclick", () => { this.fit(); this.draw(); });
  }

  click(x, y) {
    const [col, row] = this.toImage(x, y);
    const w = this.w;
    if (col < -0.5 || col > w.cols - 0.5 || row < -0.5 || row > w.rows - 0.5) return;
    const along = alongOfCol(w, col), clock = clockOfRow(w, row);
    this.pick = [col, row];
    this.readout.dataset.along = along.toFixed(4);
    this.readout.dataset.clock = clock.toFixed(2);
    this.readout.textContent = `${w.name}: ${alongName(w)} ${along.toFixed(3)} m · ${clockText(clock)} o'clock ` +
      `(${clock.toFixed(1)}°) · pixel (${col.toFixed(1)}, ${row.toFixed(1)})`;
    this.draw();
  }

  focus(col, row) {
    this.scale = Math.max(this.scale, Math.min(2, 4 * this.fitScale));
    this.ox = this.plotW / 2 - (col + 0.5) * this.scale;
    this.oy = this.plotH / 2 - (row + 0.5) * this.scale;
    this.draw();
    this.node.scrollIntoView({ block: "center" });
  }
}

function buildWalls() {
  const holder = document.getElementById("wall-list");
  if (!DATA.walls.length) holder.append(el("p", { class: "missing" }, "No unrolled walls in this result."));
  const views = {};
  for (const w of DATA.walls) {
    views[w.name] = new WallView(w, document.getElementById(w.image), holder);
  }
  for (const o of (DATA.observations && DATA.observations.rows) || []) {
    const m = o.marker;
    if (m && views[m.wall]) views[m.wall].markers.push({ ...m, label: `${o.id} ${o.code}` });
  }
  const redraw = () => Object.values(views).forEach((v) => { v.layout(); v.draw(); });
  redraw();
  let width = holder.clientWidth;
  new ResizeObserver(() => { if (holder.clientWidth !== width) { width = holder.clientWidth; redraw(); } })
    .observe(holder);
  return views;
}

// ---- deformation ----
const SOURCE_COLOURS = { sparse: "#1f77b4", dense: "#d62728" };

function niceTicks(lo, hi, count) {
  const raw = (hi - lo) / count, p = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((k) => k * p).find((s) => s >= raw);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) out.push(v);
  return { ticks: out, digits: Math.max(0, -Math.floor(Math.log10(step))) };
}

function linePlot(canvas, series, xLabel, yLabel) {
  const dpr = window.devicePixelRatio || 1;
  const W = canvas.clientWidth, H = canvas.clientHeight;
  canvas.width = W * dpr; canvas.height = H * dpr;
  const ctx = canvas.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  const L = 56, R = 10, T = 10, B = 34;
  const xs = series.flatMap((s) => s.points.map((p) => p[0])), ys = series.flatMap((s) => s.points.map((p) => p[1]));
  let [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(0, ...ys), Math.max(...ys)];
  if (x1 <= x0) x1 = x0 + 1;
  if (y1 <= y0) y1 = y0 + 1;
  const X = (x) => L + ((x - x0) / (x1 - x0)) * (W - L - R), Y = (y) => H - B - ((y - y0) / (y1 - y0)) * (H - T - B);
  ctx.font = "11px sans-serif"; ctx.fillStyle = "#333"; ctx.strokeStyle = "#ddd"; ctx.lineWidth = 1;
  const xt = niceTicks(x0, x1, 8), yt = niceTicks(y0, y1, 5);
  ctx.textAlign = "center"; ctx.textBaseline = "top";
  for (const v of xt.ticks) {
    ctx.beginPath(); ctx.moveTo(X(v), T); ctx.lineTo(X(v), H - B); ctx.stroke();
    ctx.fillText(v.toFixed(xt.digits), X(v), H - B + 3);
  }
  ctx.fillText(xLabel, (L + W - R) / 2, H - 14);
  ctx.textAlign = "right"; ctx.textBaseline = "middle";
  for (const v of yt.ticks) {
    ctx.beginPath(); ctx.moveTo(L, Y(v)); ctx.lineTo(W - R, Y(v)); ctx.stroke();
    ctx.fillText(v.toFixed(yt.digits), L - 4, Y(v));
  }
  ctx.save(); ctx.translate(12, (T + H - B) / 2); ctx.rotate(-Math.PI / 2); ctx.textAlign = "center";
  ctx.fillText(yLabel, 0, 0); ctx.restore();
  for (const s of series) {
    ctx.strokeStyle = s.colour; ctx.lineWidth = 1.5; ctx.beginPath();
    let prev = null;
    for (const p of s.points) {
      if (prev && (p[2] !== prev[2] || p[0] - prev[0] > 0.25)) ctx.moveTo(X(p[0]), Y(p[1]));
      else if (prev) ctx.lineTo(X(p[0]), Y(p[1]));
      else ctx.moveTo(X(p[0]), Y(p[1]));
      prev = p;
    }
    ctx.stroke();
  }
}

function deformation() {
  const body = document.getElementById("deformation-body");
  const rows = DATA.deformation;
  if (!rows) {
    body.append(el("p", { class: "missing" }, "No deformation.csv in this result."));
    return;
  }
  const chainage = rows.length > 0 && rows.every((r) => r.chainage_m !== null && r.chainage_m !== undefined);
  const groups = chainage ? [["all pieces", rows]] : [...new Set(rows.map((r) => r.piece))]
    .map((p) => [p, rows.filter((r) => r.piece === p)]);
  const xName = chainage ? "chainage (m)" : "h from the piece's start (m)";
  for (const [name, group] of groups) {
    if (!chainage) body.append(el("h3", {}, name));
    const sources = [...new Set(group.map((r) => r.source))];
    const legend = el("div", { class: "legend" });
    sources.forEach((s) => legend.append(el("span", { style: `color:${SOURCE_COLOURS[s] || "#555"}` }, `— ${s}`)));
    body.append(legend);
    for (const [key, label, scale] of [["ovality_pct", "ovality (%)", 1], ["max_inward_m", "max inward (mm)", 1000]]) {
      if (!group.some((r) => r[key] !== null && r[key] !== undefined)) continue;
      const canvas = el("canvas", { class: "plot", "data-plot": key });
      body.append(canvas);
      const series = sources.map((s) => ({
        colour: SOURCE_COLOURS[s] || "#555",
        points: group.filter((r) => r.source === s && r[key] !== null && r[key] !== undefined)
          .map((r) => [chainage ? r.chainage_m : r.h_m, r[key] * scale, r.piece]).sort((a, b) => a[0] - b[0]),
      })).filter((s) => s.points.length);
      if (series.length) linePlot(canvas, series, xName, label);
    }
  }
  const columns = Object.keys(rows[0] || {});
  const table = el("table", {}, el("tr", {}, ...columns.map((c) => el("th", {}, c))));
  for (const r of rows) {
    table.append(el("tr", {}, ...columns.map((c) => (typeof r[c] === "number" || r[c] === null
      ? el("td", { class: "n" }, fmt(r[c], c.endsWith("_pct") ? 2 : c === "points" ? 0 : 4)) : el("td", {}, r[c])))));
  }
  body.append(el("details", {}, el("summary", {}, `table: ${rows.length} slices`), table));
}

// ---- observations ----
function observations(views) {
  const body = document.getElementById("observations-body");
  const obs = DATA.observations;
  if (!obs) {
    body.append(el("p", { class: "missing" }, "No located observations for this result."));
    return;
  }
  const placed = obs.rows.filter((o) => o.marker).length;
  body.append(el("p", { class: "hint" }, `${obs.file}: ${obs.rows.length} observations, ${placed} marked on the ` +
    "walls; click a row to show it."));
  const clock = (d) => (d === null || d === undefined ? "–" : `${clockText(d)} (${d.toFixed(0)}°)`);
  const head = ["id", "code", "remark", "continuous", "section", "from–to", "chainage (m)", "clock", "frame",
    "image"];
  const table = el("table", {}, el("tr", {}, ...head.map((h) => el("th", {}, h))));
  for (const o of obs.rows) {
    const span = o.chainage_to_m === null || o.chainage_to_m === undefined ? fmt(o.chainage_m, 2)
      : `${fmt(o.chainage_m, 2)}–${fmt(o.chainage_to_m, 2)}`;
    const clocks = o.clock_to_deg === null || o.clock_to_deg === undefined ? clock(o.clock_from_deg)
      : `${clock(o.clock_from_deg)}–${clock(o.clock_to_deg)}`;
    const nodes = [o.from_node, o.to_node].filter((v) => v).join("–");
    const row = el("tr", { class: "obs" }, ...[o.id, o.code, o.remark, o.continuous, o.section, nodes]
      .map((v) => el("td", {}, v ?? "")), el("td", { class: "n" }, span), el("td", {}, clocks),
    el("td", { class: "n" }, fmt(o.frame, 0)), el("td", {}, o.image ?? ""));
    if (o.marker && views[o.marker.wall]) row.addEventListener("click", () => views[o.marker.wall].focus(o.marker.col, o.marker.row));
    table.append(row);
  }
  body.append(table);
}

// ---- a click asked for by the address (#probe=WALL:col:row), for automated checks ----
function probe(views) {
  const m = /probe=([^:&]+):([-\d.]+):([-\d.]+)/.exec(decodeURIComponent(location.hash));
  if (!m || !views[m[1]]) return;
  const view = views[m[1]];
  const [x, y] = view.toCanvas(Number(m[2]), Number(m[3]));
  const r = view.canvas.getBoundingClientRect();
  const at = { clientX: r.left + x, clientY: r.top + y, bubbles: true, pointerId: 1, button: 0 };
  view.canvas.dispatchEvent(new PointerEvent("pointerdown", at));
  view.canvas.dispatchEvent(new PointerEvent("pointerup", at));
  ROOT.dataset.probeAlong = view.readout.dataset.along ?? "";
  ROOT.dataset.probeClock = view.readout.dataset.clock ?? "";
  ROOT.dataset.probeScale = String(view.scale);
}

async function main() {
  header();
  const view = build3d();
  // The walls' images are img elements: once the page has loaded they are decoded, and everything below is
  // drawn before the load event ends.
  if (document.readyState !== "complete") await new Promise((done) => window.addEventListener("load", done));
  const views = buildWalls();
  deformation();
  observations(views);
  probe(views);
  ROOT.dataset.walls = String(Object.keys(views).length);
  ROOT.dataset.drawnPixels = String(view.drawnPixels());
  ROOT.dataset.outlines = view.outlines.join(" ");
  ROOT.dataset.readyMs = performance.now().toFixed(0);
  ROOT.dataset.ready = "1";
}

main().catch((e) => console.error(`pipemap viewer: ${e && e.stack ? e.stack : e}`));
