// featureslam's live viewer: the map's Gaussians from fslam-gateway rendered by Spark in a
// three.js scene with the tracked trajectory and camera, and the server's segmentation on top.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { SparkRenderer, SplatMesh, PackedSplats, utils } from "@sparkjsdev/spark";
import { decodeFrame, forEachRecord, intrinsicsFor } from "./protocol.js";

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);
// ?size=WxH fixes the view's size (tests and screenshots); else the view fills the window.
const fixedSize = (params.get("size") || "").match(/^(\d+)x(\d+)$/);

// The server's camera frame is x right, y down, z forward; three.js's is x right, y up, z back.
const kFlipYZ = new THREE.Matrix4().makeScale(1, -1, -1);

const state = {
  socket: null,
  map: params.get("map") || "",     // the map shown
  rows: [],                          // status rows from the gateway
  sessions: {},                      // session -> { map, poses: [[frame, tx, ty, tz, qx, qy, qz, qw]] }
  textQueries: false,
  intrinsics: null,                  // the view's camera; null = from the field of view
  nextId: 1,
  pending: new Map(),                // request id -> what it was
  lastSegment: null,                 // { id, mode, width, height, alpha: Uint8Array, covered, instances }
  splats: { version: 0, count: 0 },
  stats: { versions: 0, bytes: 0, lastBytes: 0, first: 0, last: 0, buildMs: 0 },
  fps: 0,
};

// --- three.js scene -------------------------------------------------------------------------
const canvas = $("view");
const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
renderer.setPixelRatio(1);  // one canvas pixel = one pixel of the views sent to the server
renderer.setClearColor(0x000000, 1);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(60, 4 / 3, 0.02, 100);
camera.position.set(0, 0, -3);
// Frames are drawn on demand (a change, or Spark asking after a sort): without a GPU a frame takes
// a second or more, and a page that draws all the time has no time left to take in map versions.
let dirtyFrames = 2, continuousUntil = 0;
function invalidate(frames = 3) { dirtyFrames = Math.max(dirtyFrames, frames); }
const spark = new SparkRenderer({ renderer, onDirty: () => invalidate() });
scene.add(spark);
// Until the user moves the view, every new map version re-frames it (autoView).
let autoView = true;
let controls = makeControls();
let splatMesh = null;

function makeControls() {
  const c = new OrbitControls(camera, canvas);
  c.enableDamping = false;
  c.addEventListener("start", () => { autoView = false; });
  c.addEventListener("change", () => {
    invalidate();
    // A mask belongs to the view it was asked from.
    if (state.lastSegment) clearMask();
  });
  return c;
}

const trajectoryGeometry = new THREE.BufferGeometry();
const trajectory = new THREE.Line(trajectoryGeometry, new THREE.LineBasicMaterial({ color: 0x33ddff }));
scene.add(trajectory);
// The current camera as a frustum (0.15 m deep, 4:3), in the camera's frame (server convention).
const frustum = (() => {
  const d = 0.15, w = d * 0.55, h = d * 0.41;
  const c = [0, 0, 0], p = [[-w, -h, d], [w, -h, d], [w, h, d], [-w, h, d]];
  const v = [];
  for (let i = 0; i < 4; ++i) v.push(...c, ...p[i], ...p[i], ...p[(i + 1) % 4]);
  v.push(-w * 0.5, -h, d, 0, -h * 1.6, d, 0, -h * 1.6, d, w * 0.5, -h, d);  // the "up" marker (image top)
  const g = new THREE.BufferGeometry();
  g.setAttribute("position", new THREE.Float32BufferAttribute(v, 3));
  const f = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color: 0xffaa00 }));
  f.matrixAutoUpdate = false;
  f.visible = false;
  return f;
})();
scene.add(frustum);

function viewSize() {
  if (fixedSize) return [Number(fixedSize[1]), Number(fixedSize[2])];
  const stage = $("stage");
  return [Math.max(1, stage.clientWidth), Math.max(1, stage.clientHeight)];
}

function currentIntrinsics() {
  const [w, h] = viewSize();
  const k = state.intrinsics;
  return k && k.width === w && k.height === h ? k : intrinsicsFor(w, h, 60);
}

// The projection of pinhole intrinsics (pixel centres at integers, so pixel edges at -0.5).
function applyIntrinsics() {
  const k = currentIntrinsics();
  const n = camera.near, f = camera.far;
  const left = (-(k.cx + 0.5) * n) / k.fx, right = ((k.width - k.cx - 0.5) * n) / k.fx;
  const top = ((k.cy + 0.5) * n) / k.fy, bottom = (-(k.height - k.cy - 0.5) * n) / k.fy;
  camera.projectionMatrix.makePerspective(left, right, top, bottom, n, f);
  camera.projectionMatrixInverse.copy(camera.projectionMatrix).invert();
}

function resize() {
  const [w, h] = viewSize();
  if (canvas.width !== w || canvas.height !== h) {
    invalidate();
    renderer.setSize(w, h, true);
    const overlay = $("overlay");
    overlay.width = w;
    overlay.height = h;
    overlay.style.width = `${w}px`;
    overlay.style.height = `${h}px`;
    camera.aspect = w / h;
  }
}

// Camera-to-world (server convention) of the three.js camera, as t and q (qx qy qz qw).
function cameraPose() {
  camera.updateMatrixWorld();
  const m = camera.matrixWorld.clone().multiply(kFlipYZ);
  const t = new THREE.Vector3(), q = new THREE.Quaternion(), s = new THREE.Vector3();
  m.decompose(t, q, s);
  return { t: [t.x, t.y, t.z], q: [q.x, q.y, q.z, q.w] };
}

// Puts the three.js camera at a camera-to-world pose in the server's convention.
function placeCamera(t, q) {
  invalidate();
  const m = new THREE.Matrix4().compose(new THREE.Vector3(...t), new THREE.Quaternion(...q).normalize(),
    new THREE.Vector3(1, 1, 1)).multiply(kFlipYZ);
  m.decompose(camera.position, camera.quaternion, new THREE.Vector3());
  // Orbit around a point 1 m ahead, so that "look" starts from this view.
  const ahead = new THREE.Vector3(0, 0, 1).applyQuaternion(new THREE.Quaternion(...q).normalize());
  controls.target.copy(new THREE.Vector3(...t).add(ahead));
  camera.updateMatrixWorld();
}

function viewOfCamera() {
  const k = currentIntrinsics();
  return { ...cameraPose(), fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy, width: k.width, height: k.height };
}

// --- the map's Gaussians --------------------------------------------------------------------
function showGaussians(header, payload) {
  const t0 = performance.now();
  const count = header.count;
  // One mesh for the map's life: each version rewrites its splats in place (a new SplatMesh per
  // version costs seconds without a GPU).
  const packedSplats = splatMesh ? splatMesh.packedSplats : null;
  const packed = packedSplats ? packedSplats.ensureSplats(count) : new Uint32Array(Math.max(1, count) * 4);
  forEachRecord(payload, count, (i, x, y, z, sx, sy, sz, qw, qx, qy, qz, r, g, b, a) => {
    utils.setPackedSplat(packed, i, x, y, z, sx, sy, sz, qx, qy, qz, qw, a, r, g, b);
  });
  if (packedSplats) {
    packedSplats.numSplats = count;
    packedSplats.needsUpdate = true;
    splatMesh.updateGenerator();
    splatMesh.updateVersion();
  } else {
    splatMesh = new SplatMesh({ packedSplats: new PackedSplats({ packedArray: packed, numSplats: count }) });
    scene.add(splatMesh);
  }
  invalidate(6);
  const first = state.splats.version === 0;
  state.splats = { version: header.version, count };
  const s = state.stats;
  const now = performance.now();
  s.versions += 1;
  s.bytes += payload.byteLength;
  s.lastBytes = payload.byteLength;
  if (s.first === 0) s.first = now;
  s.last = now;
  s.buildMs = now - t0;
  const el = $("gaussian-count");
  el.dataset.count = String(count);
  el.dataset.version = String(header.version);
  el.textContent = `${count.toLocaleString("en")} Gaussians, map version ${header.version}`;
  const span = (s.last - s.first) / 1000;
  $("rate").textContent = `${s.versions} versions received` +
    (span > 0 ? `, ${((s.versions - 1) / span).toFixed(2)} per s` : "") +
    `, last ${(s.lastBytes / 1024).toFixed(0)} KiB`;
  if ((first || autoView) && !$("follow").checked && count > 0) frameMap(payload, count);
}

// An overview: the map's middle seen from behind its first camera, far enough back to hold the
// map's spread, with that camera's image "up" as up (SLAM worlds have no fixed vertical).
function frameMap(payload, count) {
  const c = new THREE.Vector3(), p = new THREE.Vector3();
  const step = Math.max(1, Math.floor(count / 5000));
  let n = 0, spread = 0;
  forEachRecord(payload, count, (i, x, y, z) => { if (i % step === 0) { c.add(p.set(x, y, z)); ++n; } });
  c.multiplyScalar(1 / n);
  forEachRecord(payload, count, (i, x, y, z) => { if (i % step === 0) spread += p.set(x, y, z).distanceToSquared(c); });
  const radius = Math.sqrt(spread / n);
  const traj = trajectoryOf(state.map);
  const q = traj.length > 0 ? new THREE.Quaternion(traj[0][4], traj[0][5], traj[0][6], traj[0][7]).normalize() : new THREE.Quaternion();
  const forward = new THREE.Vector3(0, 0, 1).applyQuaternion(q), up = new THREE.Vector3(0, -1, 0).applyQuaternion(q);
  const distance = Math.max(1, 1.8 * radius / Math.tan(Math.PI / 6));
  if (!camera.up.equals(up)) {
    camera.up.copy(up);
    controls.dispose();  // OrbitControls takes "up" when made
    controls = makeControls();
  }
  camera.position.copy(c).addScaledVector(forward, -distance).addScaledVector(up, 0.35 * distance);
  controls.target.copy(c);
  camera.lookAt(c);
  controls.update();
}

// --- trajectories and status ----------------------------------------------------------------
function trajectoryOf(map) {
  for (const [name, s] of Object.entries(state.sessions)) {
    if (s.map === map && s.poses.length > 0) return s.poses;
  }
  return [];
}

function mapOfSession(session) {
  const row = state.rows.find((r) => r.session === session);
  return row ? row.map : (state.sessions[session] || {}).map || "";
}

function redrawTrajectory() {
  invalidate();
  const poses = trajectoryOf(state.map);
  const v = new Float32Array(poses.length * 3);
  poses.forEach((p, i) => v.set([p[1], p[2], p[3]], 3 * i));
  trajectoryGeometry.setAttribute("position", new THREE.BufferAttribute(v, 3));
  trajectoryGeometry.computeBoundingSphere();
  if (poses.length > 0) {
    const p = poses[poses.length - 1];
    frustum.matrix.compose(new THREE.Vector3(p[1], p[2], p[3]), new THREE.Quaternion(p[4], p[5], p[6], p[7]).normalize(),
      new THREE.Vector3(1, 1, 1));
    frustum.matrixWorldNeedsUpdate = true;
    frustum.visible = true;
    if ($("follow").checked) placeCamera([p[1], p[2], p[3]], [p[4], p[5], p[6], p[7]]);
  } else {
    frustum.visible = false;
  }
}

function showStatus(msg) {
  state.rows = msg.rows;
  state.textQueries = !!msg.text_queries;
  $("text").disabled = !state.textQueries;
  $("text-go").disabled = !state.textQueries;
  $("text").placeholder = state.textQueries ? "text prompt, e.g. a chair" : "text prompts need a grounding model on the server";
  for (const r of msg.rows) {
    if (r.session && state.sessions[r.session]) state.sessions[r.session].map = r.map;
  }
  if (!state.map && msg.rows.length > 0) {
    const streaming = msg.rows.find((r) => r.streaming);
    selectMap((streaming || msg.rows[0]).map);
  }
  const body = $("maps").querySelector("tbody");
  body.innerHTML = "";
  for (const r of msg.rows) {
    const tr = document.createElement("tr");
    tr.className = "map-row" + (r.map === state.map ? " selected" : "");
    const cells = [r.map, r.session || "–", r.streaming ? "streaming" : "idle",
      String(r.map_gaussians), String(r.frames_tracked)];
    for (const c of cells) {
      const td = document.createElement("td");
      td.textContent = c;
      tr.appendChild(td);
    }
    tr.dataset.map = r.map;
    tr.dataset.gaussians = String(r.map_gaussians);
    tr.dataset.version = String(r.map_version);
    tr.addEventListener("click", () => selectMap(r.map));
    body.appendChild(tr);
  }
}

function selectMap(map) {
  if (map === state.map && state.subscribed) return;
  state.map = map;
  state.subscribed = true;
  state.splats = { version: 0, count: 0 };
  state.pendingMap = null;
  if (splatMesh) {
    scene.remove(splatMesh);
    splatMesh.dispose();
    splatMesh = null;
  }
  send({ type: "subscribe", map });
  redrawTrajectory();
}

// --- segmentation and renders ---------------------------------------------------------------
function send(msg) {
  if (state.socket && state.socket.readyState === WebSocket.OPEN) state.socket.send(JSON.stringify(msg));
}

function request(type, fields) {
  if (!state.map) return 0;
  const id = state.nextId++;
  const msg = { type, id, map: state.map, view: viewOfCamera(), ...fields };
  state.pending.set(id, msg);
  $("seg-status").textContent = `${type} ${fields.mode || ""}…`;
  send(msg);
  return id;
}

async function showSegment(header, payload) {
  const bitmap = await createImageBitmap(new Blob([payload], { type: "image/png" }));
  const overlay = $("overlay");
  const ctx = overlay.getContext("2d");
  ctx.clearRect(0, 0, overlay.width, overlay.height);
  ctx.drawImage(bitmap, 0, 0, overlay.width, overlay.height);
  // The mask as the server sent it, for whoever checks it (tests): alpha > 0 = selected.
  const c = new OffscreenCanvas(header.width, header.height);
  const cctx = c.getContext("2d");
  cctx.drawImage(bitmap, 0, 0);
  const rgba = cctx.getImageData(0, 0, header.width, header.height).data;
  const alpha = new Uint8Array(header.width * header.height);
  for (let i = 0; i < alpha.length; ++i) alpha[i] = rgba[4 * i + 3];
  state.lastSegment = { ...header, alpha };
  $("seg-status").textContent = header.mode === "promptless"
    ? `${header.instances} instances (map version ${header.map_version})`
    : `${header.covered} pixels selected (map version ${header.map_version})`;
}

function showRender(header, payload) {
  const img = $("server-render");
  if (img.src) URL.revokeObjectURL(img.src);
  img.src = URL.createObjectURL(new Blob([payload], { type: "image/png" }));
  img.style.display = "block";
  $("seg-status").textContent = `server render, map version ${header.map_version}`;
}

function clearOverlay() {
  const overlay = $("overlay");
  overlay.getContext("2d").clearRect(0, 0, overlay.width, overlay.height);
  $("server-render").style.display = "none";
}

function tool() {
  return document.querySelector("input[name=tool]:checked").value;
}

let drag = null;
canvas.addEventListener("pointerdown", (e) => {
  if (tool() === "box") drag = { x0: e.offsetX, y0: e.offsetY };
});
canvas.addEventListener("pointermove", (e) => {
  if (!drag) return;
  const b = $("box");
  Object.assign(b.style, { display: "block", left: `${Math.min(drag.x0, e.offsetX)}px`, top: `${Math.min(drag.y0, e.offsetY)}px`,
    width: `${Math.abs(e.offsetX - drag.x0)}px`, height: `${Math.abs(e.offsetY - drag.y0)}px` });
});
canvas.addEventListener("pointerup", (e) => {
  if (tool() === "point") {
    // Pixel centres at integers: the pixel under the pointer is the one whose square holds it.
    request("segment", { mode: "points", points: [e.offsetX - 0.5, e.offsetY - 0.5] });
  } else if (tool() === "box" && drag) {
    const [w, h] = viewSize();
    const u0 = Math.max(0, Math.min(drag.x0, e.offsetX)), u1 = Math.min(w, Math.max(drag.x0, e.offsetX));
    const v0 = Math.max(0, Math.min(drag.y0, e.offsetY)), v1 = Math.min(h, Math.max(drag.y0, e.offsetY));
    drag = null;
    $("box").style.display = "none";
    if (u1 - u0 >= 2 && v1 - v0 >= 2) request("segment", { mode: "boxes", boxes: [u0, v0, u1, v1] });
  }
});
document.querySelectorAll("input[name=tool]").forEach((r) => r.addEventListener("change", () => {
  controls.enabled = tool() === "orbit" && !$("follow").checked;
}));
$("follow").addEventListener("change", () => {
  autoView = false;
  controls.enabled = tool() === "orbit" && !$("follow").checked;
  redrawTrajectory();
});
$("promptless").addEventListener("click", () => request("segment", { mode: "promptless" }));
$("render").addEventListener("click", () => request("render", {}));
$("clear").addEventListener("click", clearOverlay);
$("text-form").addEventListener("submit", (e) => {
  e.preventDefault();
  const text = $("text").value.trim();
  if (text) request("segment", { mode: "text", text });
});
function clearMask() {
  const overlay = $("overlay");
  overlay.getContext("2d").clearRect(0, 0, overlay.width, overlay.height);
}

// --- the connection -------------------------------------------------------------------------
function connect() {
  const scheme = location.protocol === "https:" ? "wss:" : "ws:";
  const socket = new WebSocket(`${scheme}//${location.host}/ws`);
  socket.binaryType = "arraybuffer";
  state.socket = socket;
  socket.onopen = () => {
    $("connection").textContent = "connected";
    $("connection").className = "badge ok";
    state.subscribed = false;
    if (state.map) selectMap(state.map);
  };
  socket.onclose = () => {
    $("connection").textContent = "disconnected; retrying…";
    $("connection").className = "badge";
    setTimeout(connect, 1000);
  };
  socket.onmessage = (event) => {
    if (typeof event.data !== "string") {
      const { tag, header, payload } = decodeFrame(event.data);
      // Only the newest version waiting is built, at the next frame: a page that renders slowly
      // (no GPU) skips versions instead of falling behind.
      if (tag === "GMAP" && header.map === state.map) state.pendingMap = { header, payload };
      else if (tag === "SEGM") showSegment(header, payload).then(() => state.pending.delete(header.id));
      else if (tag === "REND") { showRender(header, payload); state.pending.delete(header.id); }
      return;
    }
    const msg = JSON.parse(event.data);
    if (msg.type === "status") showStatus(msg);
    else if (msg.type === "trajectories") {
      for (const [name, s] of Object.entries(msg.sessions)) state.sessions[name] = { map: s.map, poses: s.poses };
      redrawTrajectory();
    } else if (msg.type === "pose") {
      const s = state.sessions[msg.session] || (state.sessions[msg.session] = { map: mapOfSession(msg.session), poses: [] });
      s.poses.push([msg.frame, ...msg.t, ...msg.q]);
      if (s.map === state.map || !s.map) redrawTrajectory();
    } else if (msg.ok === false) {
      state.pending.delete(msg.id);
      state.lastError = msg.error;
      $("seg-status").textContent = msg.error;
    }
  };
}

// --- the frame loop -------------------------------------------------------------------------
let frames = 0, fpsSince = performance.now();
renderer.setAnimationLoop(() => {
  if (state.pendingMap) {
    const { header, payload } = state.pendingMap;
    state.pendingMap = null;
    if (header.map === state.map) showGaussians(header, payload);
  }
  resize();
  if (controls.enabled) controls.update();
  const now = performance.now();
  if (now - fpsSince >= 1000) {
    state.fps = (frames * 1000) / (now - fpsSince);
    $("fps").textContent = `${state.fps.toFixed(1)} frames drawn per s${dirtyFrames > 0 || now < continuousUntil ? "" : " (idle)"}`;
    frames = 0;
    fpsSince = now;
  }
  if (dirtyFrames <= 0 && now >= continuousUntil) return;
  dirtyFrames -= 1;
  applyIntrinsics();
  renderer.render(scene, camera);
  ++frames;
});

// For tests and scripts: the state, and a way to look from a given camera.
window.fslamViewer = {
  state,
  // view: { t, q (qx qy qz qw, camera-to-world, server convention), fx, fy, cx, cy, width, height }
  setView(view) {
    autoView = false;
    state.intrinsics = { fx: view.fx, fy: view.fy, cx: view.cx, cy: view.cy, width: view.width, height: view.height };
    $("follow").checked = false;
    controls.enabled = false;
    placeCamera(view.t, view.q);
  },
  viewOfCamera,
  request,
  // Draws every frame for `ms` and resolves with the frame rate (benchmarks).
  measureFps(ms) {
    return new Promise((resolve) => {
      let n = 0;
      const t0 = performance.now();
      continuousUntil = t0 + ms;
      const tick = () => {
        ++n;
        if (performance.now() < continuousUntil) requestAnimationFrame(tick);
        else resolve((n * 1000) / (performance.now() - t0));
      };
      requestAnimationFrame(tick);
    });
  },
};
connect();
