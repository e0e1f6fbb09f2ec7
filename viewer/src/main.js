// The page script of `ncflow view` (bundled with three.js into src/ncflow/view/assets/viewer.js).
//
// The HTML page written by ncflow.view.page holds the data in <script type="application/json"
// id="ncflow-data">: arrays as {dtype, shape, data: base64 little-endian}, positions quantised to
// uint16 in the bounding box `bbox`. This script builds the page: three panels (source, flowed
// source animated, target) or one overlay panel, a timeline, play/pause, skeleton and colour-mode
// switches, and a colour bar for the geodesic error. It never touches the network.
//
// A page of `ncflow track` may hold the track's animation.glb (data.animation): the flowed source then
// plays the GLB's clip — skin and morph targets, evaluated by three.js's own GLTFLoader and
// AnimationMixer on the CPU — between the frames that are its keys, as a glTF viewer plays it.
//
// Test hook: window.ncflowViewer = {ready, setTime, getTime, setMode, setSkeleton, setOverlay,
// setAnimation, flowPositions, renders, error}. URL hash: #t=0.5&mode=checker&overlay=1&skeleton=0&glb=0.

import {
  AnimationMixer,
  BufferAttribute,
  BufferGeometry,
  DoubleSide,
  DynamicDrawUsage,
  LineBasicMaterial,
  LineSegments,
  LoopOnce,
  Mesh,
  PerspectiveCamera,
  Points,
  Scene,
  ShaderMaterial,
  Vector2,
  Vector3,
  WebGLRenderer,
} from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";

// what three.js's loaders call instead of fetch (build.mjs rewrites their calls): the page requests nothing
globalThis.ncflowNoNetwork = () => Promise.reject(new Error("ncflow view makes no network request"));

const MODES = { position: 0, checker: 1, error: 2, shown: 3 };
const SHOWN_COLOR = [0.95, 0.72, 0.3]; // a source vertex the target shows
const HIDDEN_COLOR = [0.22, 0.32, 0.62]; // one it does not (a scan's far side, a hole)
const PLAY_SECONDS = 3.0; // one sweep of the timeline

const VERTEX_SHADER = `
attribute vec3 ref;
attribute vec3 ecol;
varying vec3 vRef;
varying vec3 vECol;
varying vec3 vNormal;
varying vec3 vView;
void main() {
  vRef = ref;
  vECol = ecol;
  vec4 mv = modelViewMatrix * vec4(position, 1.0);
  vView = -mv.xyz;
  vNormal = normalMatrix * normal;
  gl_Position = projectionMatrix * mv;
}`;

const FRAGMENT_SHADER = `
uniform int mode;
uniform vec3 aspect;
uniform float cells;
uniform float opacity;
varying vec3 vRef;
varying vec3 vECol;
varying vec3 vNormal;
varying vec3 vView;
void main() {
  vec3 base;
  if (mode == 1) {
    vec3 c = floor(vRef * aspect * cells);
    float s = mod(c.x + c.y + c.z, 2.0);
    base = mix(vec3(0.12, 0.14, 0.22), vec3(0.97, 0.95, 0.88), s);
  } else if (mode == 2) {
    base = vECol;
  } else {
    base = vRef;
  }
  vec3 n = normalize(vNormal);
  if (!gl_FrontFacing) n = -n;
  float light = 0.35 + 0.65 * max(dot(n, normalize(vView)), 0.0);
  gl_FragColor = vec4(base * light, opacity);
}`;

const DOT_VERTEX_SHADER = `
uniform float size;
void main() {
  gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0);
  gl_PointSize = size;
}`;

const DOT_FRAGMENT_SHADER = `
uniform vec3 color;
void main() {
  vec2 d = gl_PointCoord - vec2(0.5);
  float r = length(d);
  if (r > 0.5) discard;
  gl_FragColor = vec4(r > 0.36 ? vec3(0.1) : color, 1.0);
}`;

const CSS = `
html, body { margin: 0; height: 100%; background: #1b1d23; color: #e6e6e6;
  font: 13px/1.4 system-ui, -apple-system, "Segoe UI", sans-serif; overflow: hidden; }
#ncv-root { position: fixed; inset: 0; display: flex; flex-direction: column; }
#ncv-stage { position: relative; flex: 1; min-height: 0; }
#ncv-stage canvas { display: block; width: 100%; height: 100%; touch-action: none; }
.ncv-label { position: absolute; top: 8px; padding: 2px 8px; background: rgba(0,0,0,0.45);
  border-radius: 4px; pointer-events: none; white-space: nowrap; }
#ncv-bar { display: flex; flex-wrap: wrap; align-items: center; gap: 6px 14px; padding: 8px 12px;
  background: #262932; border-top: 1px solid #3a3e4a; }
#ncv-bar button { min-width: 64px; padding: 3px 10px; background: #3a3f4d; color: inherit;
  border: 1px solid #555b6b; border-radius: 4px; cursor: pointer; font: inherit; }
#ncv-bar select { background: #3a3f4d; color: inherit; border: 1px solid #555b6b; font: inherit; }
#ncv-time { flex: 1 1 260px; min-width: 160px; }
#ncv-readout { font-variant-numeric: tabular-nums; min-width: 170px; }
#ncv-info { padding: 2px 12px 6px; background: #262932; color: #a9adb8; font-size: 12px; }
#ncv-colorbar { position: absolute; right: 10px; top: 40px; width: 210px; padding: 6px 8px; font-size: 12px;
  background: rgba(20,22,28,0.85); border: 1px solid #3a3e4a; border-radius: 6px; display: none; }
#ncv-colorbar .ncv-ramp { height: 14px; border-radius: 2px; margin: 4px 0 2px; }
#ncv-colorbar .ncv-ticks { display: flex; justify-content: space-between; font-size: 11px; }
#ncv-colorbar .ncv-nodata { display: inline-block; width: 10px; height: 10px; vertical-align: middle;
  margin-right: 4px; border-radius: 2px; }
#ncv-error { position: fixed; inset: 0; display: none; padding: 24px; background: #2a1416; color: #ffd9d9;
  white-space: pre-wrap; }
`;

// ------------------------------------------------------------------------------------------------
// Data

function base64Bytes(text) {
  const raw = atob(text);
  const bytes = new Uint8Array(raw.length);
  for (let i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
  return bytes;
}

async function inflate(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

// the inverse of ncflow.view.page.encode_array: base64, inflate, byte planes back, running sums
async function decodeArray(spec) {
  const types = { uint8: Uint8Array, uint16: Uint16Array, uint32: Uint32Array, float32: Float32Array };
  const Type = types[spec.dtype];
  if (!Type) throw new Error(`unknown array type ${spec.dtype}`);
  if (spec.codec !== "shuffle-deflate") throw new Error(`unknown array codec ${spec.codec}`);
  const count = spec.shape.reduce((a, b) => a * b, 1);
  const size = Type.BYTES_PER_ELEMENT;
  const planes = await inflate(base64Bytes(spec.data));
  if (planes.length !== count * size) throw new Error(`array of ${planes.length} bytes, expected ${count * size}`);
  const bytes = new Uint8Array(planes.length);
  for (let b = 0; b < size; b++) {
    const offset = b * count;
    for (let i = 0; i < count; i++) bytes[i * size + b] = planes[offset + i];
  }
  const out = new Type(bytes.buffer);
  if (spec.delta) {
    const row = count / spec.shape[0];
    for (let i = row; i < count; i++) out[i] += out[i - row]; // wraps modulo 2^bits, as encoded
  }
  return out;
}

function dequantise(q, bbox) {
  const out = new Float32Array(q.length);
  const lo = bbox.min;
  const step = bbox.max.map((hi, a) => (hi - lo[a]) / 65535);
  for (let i = 0; i < q.length; i += 3) {
    out[i] = lo[0] + q[i] * step[0];
    out[i + 1] = lo[1] + q[i + 1] * step[1];
    out[i + 2] = lo[2] + q[i + 2] * step[2];
  }
  return out;
}

// frames arrive as (K, 3, n) coordinate planes; the meshes want (K, n, 3)
function dequantiseFrames(q, bbox, nFrames, n) {
  const out = new Float32Array(q.length);
  for (let a = 0; a < 3; a++) {
    const lo = bbox.min[a];
    const step = (bbox.max[a] - lo) / 65535;
    for (let k = 0; k < nFrames; k++) {
      const src = (k * 3 + a) * n;
      const dst = k * n * 3 + a;
      for (let i = 0; i < n; i++) out[dst + 3 * i] = lo + q[src + i] * step;
    }
  }
  return out;
}

function unitFloats(q, scale) {
  const out = new Float32Array(q.length);
  for (let i = 0; i < q.length; i++) out[i] = q[i] / scale;
  return out;
}

// ------------------------------------------------------------------------------------------------
// Scene pieces

function surfaceGeometry(positions, faces, ref, ecol) {
  const g = new BufferGeometry();
  g.setAttribute("position", new BufferAttribute(positions, 3));
  g.setAttribute("ref", new BufferAttribute(ref, 3));
  g.setAttribute("ecol", new BufferAttribute(ecol, 3));
  g.setIndex(new BufferAttribute(faces, 1));
  g.computeVertexNormals();
  g.computeBoundingSphere();
  return g;
}

function surfaceMaterial(aspect, opacity) {
  return new ShaderMaterial({
    uniforms: {
      mode: { value: 0 },
      aspect: { value: new Vector3(...aspect) },
      cells: { value: 10.0 },
      opacity: { value: opacity },
    },
    vertexShader: VERTEX_SHADER,
    fragmentShader: FRAGMENT_SHADER,
    side: DoubleSide,
    transparent: opacity < 1,
    depthWrite: opacity >= 1,
  });
}

function skeletonPieces(parents, joints) {
  const bones = [];
  parents.forEach((p, j) => {
    if (p >= 0) bones.push(p, j);
  });
  const linePos = new Float32Array(Math.max(bones.length, 2) * 3);
  const lines = new BufferGeometry();
  lines.setAttribute("position", new BufferAttribute(linePos, 3));
  const dots = new BufferGeometry();
  dots.setAttribute("position", new BufferAttribute(new Float32Array(joints * 3), 3));
  return { bones, lines, dots };
}

function setSkeletonPose(piece, pose) {
  const lp = piece.lines.attributes.position.array;
  piece.bones.forEach((j, k) => {
    lp[3 * k] = pose[3 * j];
    lp[3 * k + 1] = pose[3 * j + 1];
    lp[3 * k + 2] = pose[3 * j + 2];
  });
  piece.dots.attributes.position.array.set(pose);
  piece.lines.attributes.position.needsUpdate = true;
  piece.dots.attributes.position.needsUpdate = true;
  piece.lines.computeBoundingSphere();
  piece.dots.computeBoundingSphere();
}

function skeletonObjects(piece, pixelRatio) {
  const lines = new LineSegments(
    piece.lines,
    new LineBasicMaterial({ color: 0xffe14d, depthTest: false, transparent: true }),
  );
  const dots = new Points(
    piece.dots,
    new ShaderMaterial({
      uniforms: { size: { value: 8 * pixelRatio }, color: { value: new Vector3(1.0, 0.3, 0.37) } },
      vertexShader: DOT_VERTEX_SHADER,
      fragmentShader: DOT_FRAGMENT_SHADER,
      depthTest: false,
      transparent: true,
    }),
  );
  lines.renderOrder = 10;
  dots.renderOrder = 11;
  return [lines, dots];
}

// ------------------------------------------------------------------------------------------------
// The page

function element(tag, attrs = {}, parent = null) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "text") el.textContent = v;
    else el.setAttribute(k, v);
  }
  if (parent) parent.appendChild(el);
  return el;
}

function formatCount(n) {
  return Number(n).toLocaleString("en-US");
}

function buildDom(data) {
  const style = document.createElement("style");
  style.textContent = CSS;
  document.head.appendChild(style);
  const root = element("div", { id: "ncv-root" }, document.body);
  const stage = element("div", { id: "ncv-stage" }, root);
  const canvas = element("canvas", { id: "ncv-canvas" }, stage);
  const labels = ["source (t = 0)", "flowed source", "target"].map((text) =>
    element("div", { class: "ncv-label", text }, stage),
  );
  const colorbar = element("div", { id: "ncv-colorbar" }, stage);
  const bar = element("div", { id: "ncv-bar" }, root);
  const play = element("button", { id: "ncv-play", type: "button", text: "Play" }, bar);
  const time = element(
    "input",
    { id: "ncv-time", type: "range", min: "0", max: "1000", step: "1", value: "0", "aria-label": "time" },
    bar,
  );
  const readout = element("span", { id: "ncv-readout" }, bar);
  const skLabel = element("label", {}, bar);
  const skeleton = element("input", { id: "ncv-skeleton", type: "checkbox" }, skLabel);
  skLabel.append(" skeleton");
  const ovLabel = element("label", {}, bar);
  const overlay = element("input", { id: "ncv-overlay", type: "checkbox" }, ovLabel);
  ovLabel.append(" overlay");
  let glb = null;
  if (data.animation) {
    const glbLabel = element("label", { title: "play animation.glb (skin and morph targets) between its keys" }, bar);
    glb = element("input", { id: "ncv-glb", type: "checkbox" }, glbLabel);
    glb.checked = true;
    glbLabel.append(" animation.glb");
  }
  const modeLabel = element("label", { text: "colour " }, bar);
  const mode = element("select", { id: "ncv-mode" }, modeLabel);
  element("option", { value: "position", text: "position" }, mode);
  element("option", { value: "checker", text: "checker" }, mode);
  if (data.error) element("option", { value: "error", text: "geodesic error" }, mode);
  if (data.seen) element("option", { value: "shown", text: "shown by the target" }, mode);
  const info = element("div", { id: "ncv-info" }, root);
  if (!data.skeleton) {
    skeleton.disabled = true;
    skLabel.title = "this result has no skeleton";
  } else {
    skeleton.checked = true;
  }
  const parts = [data.title];
  const s = data.source;
  const t = data.target;
  const shown = (m) =>
    m.n_vertices === m.n_vertices_original
      ? `${formatCount(m.n_vertices)} vertices`
      : `${formatCount(m.n_vertices_original)} vertices (shown decimated: ${formatCount(m.n_vertices)})`;
  parts.push(`source ${shown(s)}`, `target ${shown(t)}`, `${data.times.length} frames`);
  info.textContent = parts.filter(Boolean).join(" · ");
  if (data.error) {
    const cb = data.error;
    element("div", { text: cb.label }, colorbar);
    const ramp = element("div", { class: "ncv-ramp" }, colorbar);
    ramp.style.background = `linear-gradient(to right, ${cb.stops.join(", ")})`;
    const ticks = element("div", { class: "ncv-ticks" }, colorbar);
    cb.ticks.forEach((tick) => element("span", { text: tick }, ticks));
    const nodata = element("div", {}, colorbar);
    const swatch = element("span", { class: "ncv-nodata" }, nodata);
    swatch.style.background = cb.no_data;
    nodata.append("no ground truth");
    if (cb.summary) element("div", { text: cb.summary }, colorbar);
  }
  return { stage, canvas, labels, colorbar, play, time, readout, skeleton, overlay, mode, glb };
}

async function start() {
  const node = document.getElementById("ncflow-data");
  if (!node) throw new Error("no ncflow-data element in the page");
  const data = JSON.parse(node.textContent);
  if (data.format !== "ncflow-view/1") throw new Error(`unknown data format ${data.format}`);
  const ui = buildDom(data);

  const bbox = data.bbox;
  const times = data.times;
  const nFrames = times.length;
  const src = data.source;
  const tgt = data.target;
  const nv = src.n_vertices;
  const shape = data.frames.shape;
  if (shape[0] !== nFrames || shape[1] !== 3 || shape[2] !== nv) throw new Error("frames do not match the source");
  const frames = dequantiseFrames(await decodeArray(data.frames), bbox, nFrames, nv);
  const srcFaces = await decodeArray(src.faces);
  const srcRef = unitFloats(await decodeArray(src.ref), 65535);
  const tgtFaces = await decodeArray(tgt.faces);
  const tgtPos = dequantise(await decodeArray(tgt.positions), bbox);
  const tgtRef = unitFloats(await decodeArray(tgt.ref), 65535);
  const tgtECol = data.error
    ? unitFloats(await decodeArray(data.error.colors), 255)
    : new Float32Array(tgtPos.length);
  const srcECol = new Float32Array(nv * 3).fill(0.5);
  if (data.seen) {
    const seen = unitFloats(await decodeArray(data.seen.values), 255);
    for (let v = 0; v < nv; v++) {
      for (let c = 0; c < 3; c++) srcECol[3 * v + c] = HIDDEN_COLOR[c] + seen[v] * (SHOWN_COLOR[c] - HIDDEN_COLOR[c]);
    }
  }

  const srcGeom = surfaceGeometry(frames.slice(0, nv * 3), srcFaces, srcRef, srcECol);
  const flowGeom = surfaceGeometry(frames.slice(0, nv * 3), srcFaces, srcRef, srcECol);
  const tgtGeom = surfaceGeometry(tgtPos, tgtFaces, tgtRef, tgtECol);
  flowGeom.attributes.position.setUsage(DynamicDrawUsage);

  const aspect = data.aspect;
  const materials = {
    src: surfaceMaterial(aspect, 1),
    flow: surfaceMaterial(aspect, 1),
    tgt: surfaceMaterial(aspect, 1),
    ghost: surfaceMaterial(aspect, 0.35),
  };
  const scenes = { src: new Scene(), flow: new Scene(), tgt: new Scene(), overlay: new Scene() };
  scenes.src.add(new Mesh(srcGeom, materials.src));
  scenes.flow.add(new Mesh(flowGeom, materials.flow));
  scenes.tgt.add(new Mesh(tgtGeom, materials.tgt));
  scenes.overlay.add(new Mesh(flowGeom, materials.flow));
  const ghost = new Mesh(tgtGeom, materials.ghost);
  ghost.renderOrder = 5;
  scenes.overlay.add(ghost);

  const pixelRatio = Math.min(window.devicePixelRatio || 1, 2);
  let skeleton = null;
  if (data.skeleton) {
    const sk = data.skeleton;
    const poses = await decodeArray(sk.positions);
    const nj = sk.parents.length;
    const pose = (k) => poses.subarray(k * nj * 3, (k + 1) * nj * 3);
    const rest = skeletonPieces(sk.parents, nj);
    const moving = skeletonPieces(sk.parents, nj);
    const fitted = skeletonPieces(sk.parents, nj);
    setSkeletonPose(rest, pose(0));
    setSkeletonPose(moving, pose(0));
    setSkeletonPose(fitted, pose(nFrames - 1));
    const objects = [
      ...skeletonObjects(rest, pixelRatio).map((o) => [scenes.src, o]),
      ...skeletonObjects(moving, pixelRatio).map((o) => [scenes.flow, o]),
      ...skeletonObjects(moving, pixelRatio).map((o) => [scenes.overlay, o]),
      ...skeletonObjects(fitted, pixelRatio).map((o) => [scenes.tgt, o]),
    ];
    objects.forEach(([scene, o]) => scene.add(o));
    const scratch = new Float32Array(nj * 3);
    skeleton = {
      objects: objects.map(([, o]) => o),
      update(i, a) {
        const p0 = pose(i);
        const p1 = pose(Math.min(i + 1, nFrames - 1));
        for (let q = 0; q < scratch.length; q++) scratch[q] = p0[q] + a * (p1[q] - p0[q]);
        setSkeletonPose(moving, scratch);
      },
    };
  }

  const animation = data.animation ? await loadAnimation(data.animation, await decodeArray(src.kept), nFrames) : null;

  const renderer = new WebGLRenderer({ canvas: ui.canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(pixelRatio);
  renderer.setClearColor(0x1b1d23, 1);
  renderer.setScissorTest(true);

  const centre = new Vector3((bbox.min[0] + bbox.max[0]) / 2, (bbox.min[1] + bbox.max[1]) / 2, (bbox.min[2] + bbox.max[2]) / 2);
  // the first view looks down -z at the box of every frame and the target: at zoom 1 its height fills
  // a panel (with a margin); a panel too narrow for its width zooms out (see render)
  const half = [0, 1, 2].map((a) => 0.5 * (bbox.max[a] - bbox.min[a]));
  const size = Math.max(...half) || 1;
  const halfHeight = Math.max(half[1], 1e-3 * size) * 1.08;
  const halfWidth = Math.max(half[0], 1e-3 * size) * 1.08;
  const fov = 35;
  const camera = new PerspectiveCamera(fov, 1, size / 100, size * 100);
  camera.position.set(centre.x, centre.y, centre.z + half[2] + halfHeight / Math.tan((fov * Math.PI) / 360));
  const controls = new OrbitControls(camera, ui.canvas);
  controls.target.copy(centre);
  controls.update();

  const state = {
    t: times[0],
    mode: "position",
    skeleton: !!data.skeleton,
    overlay: false,
    playing: false,
    glb: !!animation,
  };
  const hook = { ready: false, renders: 0, error: null };

  function panels() {
    const w = ui.stage.clientWidth;
    const h = ui.stage.clientHeight;
    if (state.overlay) return [[scenes.overlay, 0, 0, w, h]];
    const third = Math.floor(w / 3);
    return [
      [scenes.src, 0, 0, third, h],
      [scenes.flow, third, 0, third, h],
      [scenes.tgt, 2 * third, 0, w - 2 * third, h],
    ];
  }

  function layoutLabels() {
    const list = panels();
    const target = state.mode === "error" ? "target: geodesic error" : "target";
    const seen = state.mode === "shown" ? ": shown by the target (orange) or not (blue)" : "";
    const names = state.overlay
      ? [`flowed source${seen} over the ${target} (transparent)`]
      : [`source (t = 0)${seen}`, "flowed source", target];
    ui.labels.forEach((label, i) => {
      const p = list[i];
      label.style.display = p ? "block" : "none";
      if (!p) return;
      label.textContent = names[i];
      label.style.left = `${p[1] + 8}px`;
    });
  }

  function render() {
    const w = ui.stage.clientWidth;
    const h = ui.stage.clientHeight;
    const size = renderer.getSize(new Vector2());
    if (size.x !== w || size.y !== h) renderer.setSize(w, h, false);
    for (const [scene, x, y, pw, ph] of panels()) {
      renderer.setViewport(x, y, pw, ph);
      renderer.setScissor(x, y, pw, ph);
      camera.aspect = pw / Math.max(ph, 1);
      camera.zoom = Math.min((camera.aspect * halfHeight) / halfWidth, 1);
      camera.updateProjectionMatrix();
      renderer.render(scene, camera);
    }
    hook.renders += 1;
  }

  let pending = false;
  function requestRender() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => {
      pending = false;
      render();
    });
  }

  function frameAt(t) {
    if (t <= times[0]) return [0, 0];
    if (t >= times[nFrames - 1]) return [Math.max(nFrames - 2, 0), nFrames > 1 ? 1 : 0];
    let i = 0;
    while (i < nFrames - 2 && times[i + 1] < t) i++;
    const span = times[i + 1] - times[i];
    return [i, span > 0 ? (t - times[i]) / span : 0];
  }

  const flowPos = flowGeom.attributes.position.array;
  function applyTime(t) {
    const t0 = times[0];
    const t1 = times[nFrames - 1];
    state.t = Math.min(Math.max(Number(t) || 0, t0), t1);
    const [i, a] = frameAt(state.t);
    const j = Math.min(i + 1, nFrames - 1);
    const f0 = i * nv * 3;
    const f1 = j * nv * 3;
    if (state.glb && animation && animation.keys[i] >= 0 && animation.keys[j] >= 0) {
      const k0 = animation.keyTimes[animation.keys[i]];
      animation.positionsAt(k0 + a * (animation.keyTimes[animation.keys[j]] - k0), flowPos);
    } else {
      for (let q = 0; q < nv * 3; q++) flowPos[q] = frames[f0 + q] + a * (frames[f1 + q] - frames[f0 + q]);
    }
    flowGeom.attributes.position.needsUpdate = true;
    flowGeom.computeVertexNormals();
    if (skeleton) skeleton.update(i, a);
    const frac = t1 > t0 ? (state.t - t0) / (t1 - t0) : 0;
    ui.time.value = String(Math.round(frac * 1000));
    ui.readout.textContent = `t = ${state.t.toFixed(3)} · frame ${(i + a + 1).toFixed(1)} / ${nFrames}`;
  }

  function applyMode(mode) {
    if (!(mode in MODES) || (mode === "error" && !data.error) || (mode === "shown" && !data.seen)) mode = "position";
    state.mode = mode;
    ui.mode.value = mode;
    const code = MODES[mode];
    // error: the target's colours; shown: the source's (what the target shows of it)
    const onSource = code === 3 ? 2 : code === 2 ? 0 : code;
    const onTarget = code === 3 ? 0 : code;
    materials.src.uniforms.mode.value = onSource;
    materials.flow.uniforms.mode.value = onSource;
    materials.tgt.uniforms.mode.value = onTarget;
    materials.ghost.uniforms.mode.value = onTarget;
    ui.colorbar.style.display = code === 2 ? "block" : "none";
    layoutLabels();
  }

  function applySkeleton(on) {
    state.skeleton = !!on && !!skeleton;
    ui.skeleton.checked = state.skeleton;
    if (skeleton) skeleton.objects.forEach((o) => (o.visible = state.skeleton));
  }

  function applyOverlay(on) {
    state.overlay = !!on;
    ui.overlay.checked = state.overlay;
    layoutLabels();
  }

  function applyAnimation(on) {
    state.glb = !!on && !!animation;
    if (ui.glb) ui.glb.checked = state.glb;
    applyTime(state.t);
  }

  function setPlaying(on) {
    state.playing = !!on;
    ui.play.textContent = state.playing ? "Pause" : "Play";
    if (state.playing) {
      if (state.t >= times[nFrames - 1]) applyTime(times[0]);
      last = null;
      requestAnimationFrame(tick);
    }
  }

  let last = null;
  function tick(now) {
    if (!state.playing) return;
    if (last !== null) {
      const span = times[nFrames - 1] - times[0];
      let t = state.t + ((now - last) / 1000 / PLAY_SECONDS) * span;
      if (t > times[nFrames - 1]) t = times[0] + (t - times[nFrames - 1]);
      applyTime(t);
      render();
    }
    last = now;
    requestAnimationFrame(tick);
  }

  function applyHash() {
    const params = new URLSearchParams(window.location.hash.replace(/^#/, ""));
    if (params.has("t")) applyTime(parseFloat(params.get("t")));
    if (params.has("mode")) applyMode(params.get("mode"));
    if (params.has("skeleton")) applySkeleton(params.get("skeleton") !== "0");
    if (params.has("overlay")) applyOverlay(params.get("overlay") !== "0");
    if (params.has("glb")) applyAnimation(params.get("glb") !== "0");
  }

  ui.time.addEventListener("input", () => {
    const frac = Number(ui.time.value) / 1000;
    applyTime(times[0] + frac * (times[nFrames - 1] - times[0]));
    requestRender();
  });
  ui.play.addEventListener("click", () => setPlaying(!state.playing));
  ui.skeleton.addEventListener("change", () => {
    applySkeleton(ui.skeleton.checked);
    requestRender();
  });
  ui.overlay.addEventListener("change", () => {
    applyOverlay(ui.overlay.checked);
    requestRender();
  });
  if (ui.glb) {
    ui.glb.addEventListener("change", () => {
      applyAnimation(ui.glb.checked);
      requestRender();
    });
  }
  ui.mode.addEventListener("change", () => {
    applyMode(ui.mode.value);
    requestRender();
  });
  window.addEventListener("keydown", (ev) => {
    const tag = ev.target && ev.target.tagName;
    if (tag === "INPUT" || tag === "SELECT" || tag === "BUTTON") return; // they handle their own keys
    if (ev.key === " ") {
      ev.preventDefault();
      setPlaying(!state.playing);
    } else if (ev.key === "ArrowLeft" || ev.key === "ArrowRight") {
      const [i, a] = frameAt(state.t);
      const at = i + a; // fractional frame index
      const k = ev.key === "ArrowRight" ? Math.floor(at + 1e-6) + 1 : Math.ceil(at - 1e-6) - 1;
      applyTime(times[Math.min(Math.max(k, 0), nFrames - 1)]);
      requestRender();
    }
  });
  window.addEventListener("hashchange", () => {
    applyHash();
    requestRender();
  });
  window.addEventListener("resize", () => {
    layoutLabels();
    requestRender();
  });
  controls.addEventListener("change", requestRender);

  applyTime(times[0]);
  applyMode("position");
  applySkeleton(state.skeleton);
  applyOverlay(false);
  applyHash();
  render();

  Object.assign(hook, {
    ready: true,
    frames: nFrames,
    times: times.slice(),
    setTime(t) {
      applyTime(t);
      render();
      return state.t;
    },
    getTime: () => state.t,
    setMode(m) {
      applyMode(m);
      render();
      return state.mode;
    },
    setSkeleton(on) {
      applySkeleton(on);
      render();
    },
    setOverlay(on) {
      applyOverlay(on);
      render();
    },
    setAnimation(on) {
      applyAnimation(on);
      render();
      return state.glb;
    },
    flowPositions: () => Array.from(flowPos),
    play: () => setPlaying(true),
    pause: () => setPlaying(false),
    state: () => ({ ...state }),
  });
  return hook;
}

// animation.glb in three.js: its skinned mesh, posed by the clip at a time, read back vertex by vertex
// (SkinnedMesh.getVertexPosition: morph targets, then the bones) for the page's kept vertices
async function loadAnimation(spec, kept, nFrames) {
  if (spec.keys.length !== nFrames) throw new Error("the animation's keys do not match the frames");
  const bytes = await decodeArray(spec.glb);
  const gltf = await new GLTFLoader().parseAsync(bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength), "");
  let skinned = null;
  gltf.scene.traverse((o) => {
    if (o.isSkinnedMesh && !skinned) skinned = o;
  });
  if (!skinned || !gltf.animations.length) throw new Error("animation.glb has no skinned mesh or no clip");
  const clip = gltf.animations[0];
  const keyTimes = Array.from(clip.tracks[0].times);
  if (spec.keys.some((k) => k >= keyTimes.length)) throw new Error("animation.glb has fewer keys than the track");
  const mixer = new AnimationMixer(gltf.scene);
  const action = mixer.clipAction(clip);
  action.setLoop(LoopOnce, 1);
  action.clampWhenFinished = true;
  action.play();
  const v = new Vector3();
  return {
    keys: spec.keys,
    keyTimes,
    positionsAt(t, out) {
      action.time = Math.min(Math.max(t, 0), clip.duration);
      action.enabled = true;
      action.paused = false;
      mixer.update(0);
      gltf.scene.updateMatrixWorld(true);
      for (let q = 0; q < kept.length; q++) {
        skinned.getVertexPosition(kept[q], v).applyMatrix4(skinned.matrixWorld);
        out[3 * q] = v.x;
        out[3 * q + 1] = v.y;
        out[3 * q + 2] = v.z;
      }
    },
  };
}

function showError(err) {
  const box = document.createElement("div");
  box.id = "ncv-error";
  box.style.display = "block";
  box.textContent = `ncflow view: this page cannot show the result.\n\n${err && err.message ? err.message : err}`;
  document.body.appendChild(box);
}

window.ncflowViewer = { ready: false, error: null };
start().then(
  (hook) => {
    window.ncflowViewer = hook;
  },
  (err) => {
    window.ncflowViewer = { ready: false, error: String(err && err.message ? err.message : err) };
    showError(err);
    console.error(err);
  },
);
