// visloc map viewer: the page's own code (three.js draws). Reads the JSON
// block #visloc-data written by `visloc view` (src/visloc/viewer/viewer.cc).
// Frame: z up, metres; positions are relative to data.origin.
import * as THREE from 'three';

const appStartMs = performance.now();  // three.js is parsed by now

const errors = [];
window.addEventListener('error', (e) => errors.push(String(e.message || e)));
window.addEventListener('unhandledrejection', (e) => errors.push(String(e.reason)));
const consoleError = console.error.bind(console);
console.error = (...args) => { errors.push(args.map(String).join(' ')); consoleError(...args); };

const data = JSON.parse(document.getElementById('visloc-data').textContent);

function bytesOf(base64) {
  const text = atob(base64);
  const out = new Uint8Array(text.length);
  for (let i = 0; i < text.length; ++i) out[i] = text.charCodeAt(i);
  return out;
}

function segmentColor(index) {  // well-separated hues, golden-ratio steps
  return new THREE.Color().setHSL((index * 0.61803398875) % 1, 0.65, 0.58);
}

// Error colour: green under 0.25 m, yellow to 1 m, orange to 5 m, red beyond.
function errorColor(metres) {
  if (metres < 0) return new THREE.Color(0x888888);
  if (metres <= 0.25) return new THREE.Color(0x2ca02c);
  if (metres <= 1) return new THREE.Color(0xd6c400);
  if (metres <= 5) return new THREE.Color(0xff8c1a);
  return new THREE.Color(0xe03030);
}

const container = document.getElementById('view');
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio || 1);
renderer.setSize(window.innerWidth, window.innerHeight);
container.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x16181d);
const extent = Math.max(data.extent, 1);
const camera = new THREE.PerspectiveCamera(50, window.innerWidth / window.innerHeight, extent * 1e-4, extent * 50);
camera.up.set(0, 0, 1);
const layers = {};

// Map points, coloured by segment.
{
  const n = data.points.count;
  const q = new Uint16Array(bytesOf(data.points.xyz_u16).buffer);
  const seg = new Uint16Array(bytesOf(data.points.segment_u16).buffer);
  const position = new Float32Array(3 * n);
  const color = new Float32Array(3 * n);
  const lo = data.points.min, step = data.points.step;
  const palette = data.segments.map((s, i) => segmentColor(i));
  for (let i = 0; i < n; ++i) {
    for (let k = 0; k < 3; ++k) position[3 * i + k] = lo[k] + q[3 * i + k] * step[k];
    const c = palette[seg[i]] || palette[0];
    color[3 * i] = c.r; color[3 * i + 1] = c.g; color[3 * i + 2] = c.b;
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(position, 3));
  geometry.setAttribute('color', new THREE.BufferAttribute(color, 3));
  const points = new THREE.Points(geometry, new THREE.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: true }));
  points.name = 'map points';
  layers.points = points;
  scene.add(points);
}

// Map cameras as frusta: apex at the centre, a rectangle `depth` ahead.
{
  const c = new Float32Array(bytesOf(data.cameras.data_f32).buffer);  // per camera: centre(3), R columns(9), w, h, f, segment
  const n = data.cameras.count;
  const depth = data.camera_depth;
  const position = new Float32Array(n * 16 * 3);
  const color = new Float32Array(n * 16 * 3);
  let v = 0;
  const push = (p, col) => { position.set(p, 3 * v); color.set([col.r, col.g, col.b], 3 * v); ++v; };
  for (let i = 0; i < n; ++i) {
    const o = 16 * i;
    const C = [c[o], c[o + 1], c[o + 2]];
    const X = [c[o + 3], c[o + 4], c[o + 5]], Y = [c[o + 6], c[o + 7], c[o + 8]], Z = [c[o + 9], c[o + 10], c[o + 11]];
    const w = c[o + 12], h = c[o + 13], f = c[o + 14] > 0 ? c[o + 14] : Math.max(w, h, 1);
    const col = segmentColor(c[o + 15]).multiplyScalar(0.8);
    const corner = (sx, sy) => [0, 1, 2].map((k) => C[k] + depth * (sx * (w / (2 * f)) * X[k] + sy * (h / (2 * f)) * Y[k] + Z[k]));
    const k4 = [corner(-1, -1), corner(1, -1), corner(1, 1), corner(-1, 1)];
    for (let j = 0; j < 4; ++j) { push(C, col); push(k4[j], col); }
    for (let j = 0; j < 4; ++j) { push(k4[j], col); push(k4[(j + 1) % 4], col); }
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(position, 3));
  geometry.setAttribute('color', new THREE.BufferAttribute(color, 3));
  const frusta = new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ vertexColors: true }));
  frusta.name = 'map cameras';
  frusta.userData.cameras = n;
  layers.cameras = frusta;
  scene.add(frusta);
}

// Ground grid in metres at the lowest segment's ground, spacing a round number.
const ground = data.ground_z;
const spacing = data.grid_spacing;
{
  const [x0, y0, x1, y1] = data.grid_box;
  const position = [];
  for (let x = x0; x <= x1 + 1e-9; x += spacing) position.push(x, y0, ground, x, y1, ground);
  for (let y = y0; y <= y1 + 1e-9; y += spacing) position.push(x0, y, ground, x1, y, ground);
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.Float32BufferAttribute(position, 3));
  const grid = new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ color: 0x3a3f4b }));
  grid.name = 'grid';
  layers.grid = grid;
  scene.add(grid);
  if (data.north) {  // a north arrow on the grid's corner, when the map is georegistered
    const len = 2 * spacing;
    const base = new THREE.Vector3(x0 + spacing, y0 + spacing, ground);
    grid.add(new THREE.ArrowHelper(new THREE.Vector3(...data.north), base, len, 0xffffff, 0.3 * len, 0.15 * len));
  }
}

// Segment outlines on the ground, their ids as labels.
const segmentLabels = [];
{
  const group = new THREE.Group();
  group.name = 'segments';
  data.segments.forEach((s, i) => {
    if (s.outline.length < 2) return;
    const pts = s.outline.map(([x, y]) => new THREE.Vector3(x, y, s.ground_z));
    const line = new THREE.LineLoop(new THREE.BufferGeometry().setFromPoints(pts),
                                    new THREE.LineBasicMaterial({ color: segmentColor(i) }));
    group.add(line);
    const centre = pts.reduce((a, p) => a.add(p), new THREE.Vector3()).multiplyScalar(1 / pts.length);
    const el = document.createElement('div');
    el.className = 'seglabel';
    el.textContent = String(s.id);
    el.style.color = '#' + segmentColor(i).getHexString();
    document.getElementById('labels').appendChild(el);
    segmentLabels.push({ el, centre });
  });
  layers.segments = group;
  scene.add(group);
}

// Queries: truth (green), estimate (red), joined by a line coloured by the
// error; wrong poses ringed in magenta; misses crossed at the truth.
const queryMarkers = [];
{
  const group = new THREE.Group();
  group.name = 'queries';
  const r = data.query_marker_radius;
  const sphere = new THREE.SphereGeometry(r, 12, 8);
  const truthMaterial = new THREE.MeshBasicMaterial({ color: 0x2ca02c });
  const estimateMaterial = new THREE.MeshBasicMaterial({ color: 0xe03030 });
  const wrongMaterial = new THREE.MeshBasicMaterial({ color: 0xe377c2 });
  const ring = new THREE.TorusGeometry(2.2 * r, 0.35 * r, 6, 24);
  const addLine = (a, b, color) => group.add(new THREE.Line(new THREE.BufferGeometry().setFromPoints([a, b]),
                                                             new THREE.LineBasicMaterial({ color })));
  for (const q of data.queries) {
    const t = q.true_center ? new THREE.Vector3(...q.true_center) : null;
    const e = q.estimated_center ? new THREE.Vector3(...q.estimated_center) : null;
    const marker = new THREE.Group();
    marker.userData.query = q;
    if (t) {
      const m = new THREE.Mesh(sphere, truthMaterial);
      m.position.copy(t);
      marker.add(m);
      if (q.true_view_direction) addLine(t, t.clone().addScaledVector(new THREE.Vector3(...q.true_view_direction), 4 * r), 0x2ca02c);
    }
    if (e) {
      const m = new THREE.Mesh(sphere, q.wrong ? wrongMaterial : estimateMaterial);
      m.position.copy(e);
      marker.add(m);
      if (q.estimated_view_direction) addLine(e, e.clone().addScaledVector(new THREE.Vector3(...q.estimated_view_direction), 4 * r), 0xe03030);
      if (t) addLine(t, e, errorColor(q.position_error_m));
      if (q.wrong) {
        const w = new THREE.Mesh(ring, wrongMaterial);
        w.position.copy(e);
        marker.add(w);
      }
    } else if (t && !q.negative) {  // a miss
      const d = 2 * r;
      const cross = new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints([
        new THREE.Vector3(t.x - d, t.y - d, t.z), new THREE.Vector3(t.x + d, t.y + d, t.z),
        new THREE.Vector3(t.x - d, t.y + d, t.z), new THREE.Vector3(t.x + d, t.y - d, t.z)]),
        new THREE.LineBasicMaterial({ color: 0xffffff }));
      marker.add(cross);
    }
    group.add(marker);
    queryMarkers.push(marker);
  }
  layers.queries = group;
  scene.add(group);
}

// Camera control: orbit (left drag), pan (right or shift drag), zoom (wheel),
// around a target, z up.
const view = { target: new THREE.Vector3(...data.view_target), distance: 1.3 * extent, azimuth: -Math.PI / 2, elevation: 0.95 };
const home = { ...view, target: view.target.clone() };
function placeCamera() {
  const ce = Math.cos(view.elevation);
  camera.position.set(view.target.x + view.distance * ce * Math.cos(view.azimuth),
                      view.target.y + view.distance * ce * Math.sin(view.azimuth),
                      view.target.z + view.distance * Math.sin(view.elevation));
  camera.lookAt(view.target);
}
let drag = null;
renderer.domElement.addEventListener('contextmenu', (e) => e.preventDefault());
renderer.domElement.addEventListener('pointerdown', (e) => {
  drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey, moved: false };
  renderer.domElement.setPointerCapture(e.pointerId);
});
renderer.domElement.addEventListener('pointermove', (e) => {
  if (!drag) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
  if (Math.abs(dx) + Math.abs(dy) > 2) drag.moved = true;
  drag.x = e.clientX; drag.y = e.clientY;
  if (drag.pan) {
    const perPixel = 2 * view.distance * Math.tan(THREE.MathUtils.degToRad(camera.fov / 2)) / window.innerHeight;
    const right = new THREE.Vector3().setFromMatrixColumn(camera.matrixWorld, 0);
    const up = new THREE.Vector3().setFromMatrixColumn(camera.matrixWorld, 1);
    view.target.addScaledVector(right, -dx * perPixel).addScaledVector(up, dy * perPixel);
  } else {
    view.azimuth -= dx * 0.006;
    view.elevation = Math.min(Math.PI / 2 - 1e-3, Math.max(-Math.PI / 2 + 1e-3, view.elevation + dy * 0.006));
  }
  requestRender();
});
renderer.domElement.addEventListener('pointerup', (e) => {
  if (drag && !drag.moved) pick(e.clientX, e.clientY);
  drag = null;
});
renderer.domElement.addEventListener('wheel', (e) => {
  e.preventDefault();
  view.distance = Math.min(extent * 40, Math.max(extent * 1e-3, view.distance * Math.exp(e.deltaY * 0.001)));
  requestRender();
}, { passive: false });
function topView() { view.elevation = Math.PI / 2 - 1e-3; view.azimuth = -Math.PI / 2; requestRender(); }
function resetView() { Object.assign(view, home, { target: home.target.clone() }); requestRender(); }
document.getElementById('top').onclick = topView;
document.getElementById('reset').onclick = resetView;
window.addEventListener('keydown', (e) => {
  if (e.key === 't' || e.key === 'T') topView();
  if (e.key === 'r' || e.key === 'R') resetView();
});
window.addEventListener('resize', () => {
  camera.aspect = window.innerWidth / window.innerHeight;
  camera.updateProjectionMatrix();
  renderer.setSize(window.innerWidth, window.innerHeight);
  requestRender();
});

// Clicking a query shows what the report says about it.
const raycaster = new THREE.Raycaster();
function pick(x, y) {
  const ndc = new THREE.Vector2(2 * x / window.innerWidth - 1, 1 - 2 * y / window.innerHeight);
  raycaster.setFromCamera(ndc, camera);
  const hits = layers.queries.visible ? raycaster.intersectObjects(queryMarkers, true) : [];
  const info = document.getElementById('info');
  if (!hits.length) { info.style.display = 'none'; return; }
  let o = hits[0].object;
  while (o && !o.userData.query) o = o.parent;
  showQuery(o.userData.query);
}
function fmt(v, digits = 3) { return v === undefined || v === null || v < 0 ? '–' : Number(v).toPrecision(digits); }
function showQuery(q) {
  const t = q.times_ms || {};
  const status = q.negative ? (q.registered ? 'negative, REGISTERED (wrong pose)' : 'negative, not registered')
                            : (q.registered ? (q.wrong ? 'registered, WRONG pose' : 'registered') : 'miss');
  const info = document.getElementById('info');
  info.textContent = `${q.image}\n${status}\ninliers ${q.inliers}   confidence ${fmt(q.confidence)}\n` +
    `position error ${fmt(q.position_error_m)} m   rotation error ${fmt(q.rotation_error_deg)}°\n` +
    `segment ${q.segment}\ntimes (ms): features ${fmt(t.features)}, retrieval ${fmt(t.retrieval)}, ` +
    `matching ${fmt(t.matching)}, RANSAC ${fmt(t.ransac)}, total ${fmt(t.total)}`;
  info.style.display = 'block';
  window.visloc_selected = q.image;
}

// Panels: counts, layer toggles, legend.
document.getElementById('title').textContent = data.title;
document.title = data.title;
const counts = {
  points: layers.points.geometry.attributes.position.count,
  cameras: layers.cameras.userData.cameras,
  queries: queryMarkers.length,
  segments: data.segments.length,
};
document.getElementById('counts').textContent =
  `${counts.segments} segments · ${counts.points.toLocaleString('en')} of ${data.points.in_map.toLocaleString('en')} points · ` +
  `${counts.cameras} cameras` + (data.has_report ? ` · ${counts.queries} queries` : '') + ` · frame ${data.frame}`;
for (const name of ['points', 'cameras', 'grid', 'segments', 'queries']) {
  if (name === 'queries' && !data.has_report) continue;
  const label = document.createElement('label');
  const box = document.createElement('input');
  box.type = 'checkbox';
  box.checked = true;
  box.id = 'layer-' + name;
  box.onchange = () => { layers[name].visible = box.checked; requestRender(); };
  label.append(box, ' ' + name);
  document.getElementById('layers').appendChild(label);
}
document.getElementById('legend').innerHTML = data.has_report
  ? 'queries:<span style="background:#2ca02c"></span>truth<span style="background:#e03030"></span>estimate' +
    '<span style="background:#e377c2"></span>wrong pose · ✕ miss · line: error ≤0.25 / 1 / 5 / &gt;5 m'
  : 'points and camera frusta coloured by segment';

// Scale bar and compass, from the projection of the view target.
function updateOverlay() {
  const w = window.innerWidth, h = window.innerHeight;
  const toScreen = (p) => { const v = p.clone().project(camera); return [(v.x + 1) * w / 2, (1 - v.y) * h / 2, v.z]; };
  const a = toScreen(view.target);
  const b = toScreen(view.target.clone().add(camera.getWorldDirection(new THREE.Vector3()).cross(camera.up).normalize().multiplyScalar(spacing)));
  const px = Math.hypot(b[0] - a[0], b[1] - a[1]);
  document.getElementById('scalebar').style.width = `${Math.max(2, Math.min(px, 300)).toFixed(0)}px`;
  document.getElementById('scaletext').textContent = `${spacing} m (grid)`;
  const compass = document.getElementById('compass');
  if (data.north) {
    const n = toScreen(view.target.clone().addScaledVector(new THREE.Vector3(...data.north), spacing));
    const angle = Math.atan2(n[0] - a[0], a[1] - n[1]) * 180 / Math.PI;
    compass.innerHTML = `<g transform="rotate(${angle.toFixed(1)})"><path d="M0,-18 L6,6 L0,2 L-6,6 Z" fill="#e8e8e8"/>` +
      '<text y="17" text-anchor="middle" fill="#e8e8e8" font-size="10">N</text></g>';
  } else {
    compass.innerHTML = '<text y="4" text-anchor="middle" fill="#aab" font-size="9">no north</text>';
  }
  for (const { el, centre } of segmentLabels) {
    const [x, y, z] = toScreen(centre);
    el.style.display = layers.segments.visible && z < 1 ? 'block' : 'none';
    el.style.left = `${x}px`;
    el.style.top = `${y}px`;
  }
}

let pending = false;
function render() {
  pending = false;
  placeCamera();
  renderer.render(scene, camera);
  updateOverlay();
  publishStats();
}
function requestRender() { if (!pending) { pending = true; requestAnimationFrame(render); } }

// What the canvas shows, read back from WebGL after the first frame: the
// fraction of pixels that are not background, and how many are strongly
// coloured (the segments' colours; panels are HTML, not on the canvas).
function canvasContent() {
  const gl = renderer.getContext();
  const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
  const px = new Uint8Array(w * h * 4);
  gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
  const bg = [0x16, 0x18, 0x1d];
  let drawn = 0, coloured = 0;
  for (let i = 0; i < w * h; ++i) {
    const r = px[4 * i], g = px[4 * i + 1], b = px[4 * i + 2];
    if (Math.abs(r - bg[0]) + Math.abs(g - bg[1]) + Math.abs(b - bg[2]) <= 6) continue;
    ++drawn;
    if (Math.max(r, g, b) - Math.min(r, g, b) > 60) ++coloured;
  }
  return { drawn_fraction: drawn / (w * h), coloured_pixels: coloured };
}

// What a test reads (window.visloc_scene, and #visloc-stats for --dump-dom).
let loadMs = null;
let canvas = null;
function publishStats() {
  window.visloc_scene = { ...counts, load_ms: loadMs, errors: errors.slice(), frame: data.frame, canvas,
                          timings: window.visloc_timings };
  document.getElementById('visloc-stats').textContent = JSON.stringify(window.visloc_scene);
}
// #select=N: open query N's details as a click would (tests, links).
const selected = /#select=(\d+)/.exec(location.hash);
if (selected && data.queries[Number(selected[1])]) showQuery(data.queries[Number(selected[1])]);
// #noui: the canvas alone (screenshots for tests and the README).
if (location.hash === '#noui') {
  for (const el of document.querySelectorAll('.panel, #labels')) el.style.display = 'none';
}
const sceneBuiltMs = performance.now();
render();
loadMs = performance.now();
canvas = canvasContent();
// Where the load time went (ms since navigation start).
window.visloc_timings = { app_start: appStartMs, scene_built: sceneBuiltMs, first_frame: loadMs };
publishStats();
