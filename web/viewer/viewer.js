// viewer.js -- the TetWeave viewer page: open, drop or ?file=URL a .tw file, decode it in a worker (TWLoader) and
// show the mesh with orbit controls, its bytes, faces, vertices, points and decode time, at a chosen level.
// body[data-state] is idle, loading, ready or error (what the browser test waits for).
import {
  Color,
  DirectionalLight,
  DoubleSide,
  HemisphereLight,
  Mesh,
  MeshStandardMaterial,
  PerspectiveCamera,
  Scene,
  WebGLRenderer,
} from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { TWLoader } from "../TWLoader.js";

const LEVEL_NAMES = ["control", "smoothed", "full"];
const $ = (id) => document.getElementById(id);
const canvas = $("view");
const renderer = new WebGLRenderer({ canvas, antialias: true });
renderer.setPixelRatio(window.devicePixelRatio);
const scene = new Scene();
scene.background = new Color(0x1d2026);
const camera = new PerspectiveCamera(40, 1, 0.01, 100);
camera.position.set(0, 0, 3);
const light = new DirectionalLight(0xffffff, 2.0);
light.position.set(1, 1.5, 2);
camera.add(light); // a headlight: the side one looks at is always lit
scene.add(camera, new HemisphereLight(0xffffff, 0x30343c, 1.2));
const material = new MeshStandardMaterial({ color: 0xc9ccd6, roughness: 0.65, metalness: 0.0, side: DoubleSide });
const mesh = new Mesh(undefined, material);
mesh.visible = false;
scene.add(mesh);
const controls = new OrbitControls(camera, canvas);
const render = () => renderer.render(scene, camera);
controls.addEventListener("change", render);

function resize() {
  renderer.setSize(window.innerWidth, window.innerHeight, false);
  camera.aspect = window.innerWidth / Math.max(window.innerHeight, 1);
  camera.updateProjectionMatrix();
  render();
}
window.addEventListener("resize", resize);
resize();

const loader = new TWLoader().setDecoderPath(new URL("../", import.meta.url).href);
let current = null; // { name, buffer } of the file on screen
let sequence = 0; // the latest request wins when files or levels change faster than they decode

const level = () => document.querySelector('input[name="level"]:checked').value;

function setState(state, status = "") {
  document.body.dataset.state = state;
  $("status").textContent = status;
}

function showError(message) {
  $("error").textContent = message;
  $("error").hidden = false;
  setState("error");
}

function setInfo(id, value, text = value.toLocaleString()) {
  $(id).textContent = text;
  $(id).dataset.value = String(value);
}

function fitCamera(geometry) {
  geometry.computeBoundingSphere();
  const { center, radius } = geometry.boundingSphere;
  const r = radius > 0 ? radius : 1;
  const distance = (r / Math.sin((camera.fov * Math.PI) / 360)) * 1.1;
  controls.target.copy(center);
  // a three-quarter view: meshes come in any orientation, and one seen straight along an axis often hides its shape
  camera.position.set(center.x + 0.6 * distance, center.y + 0.35 * distance, center.z + 0.72 * distance);
  camera.near = distance / 100;
  camera.far = distance * 10;
  camera.updateProjectionMatrix();
  controls.update();
}

/** Decode `buffer` (ArrayBuffer) at the chosen level and show it; a new file (newFile) also refits the camera. */
async function show(buffer, name, newFile) {
  const request = ++sequence;
  $("error").hidden = true;
  setState("loading", `decoding ${name} (${level()})...`);
  let geometry;
  try {
    geometry = await loader.parse(buffer, { level: level() });
  } catch (error) {
    if (request === sequence) showError(`cannot decode ${name}: ${error.message}`);
    return;
  }
  if (request !== sequence) {
    geometry.dispose();
    return;
  }
  const info = geometry.userData.tetweave;
  mesh.geometry.dispose();
  mesh.geometry = geometry;
  mesh.visible = true;
  current = { name, buffer };
  if (newFile && info.faceCount > 0) fitCamera(geometry); // an empty mesh (all s of one sign) has no sphere
  setInfo("name", name, name);
  setInfo("bytes", info.bytes);
  setInfo("faces", info.faceCount);
  setInfo("vertices", info.vertexCount);
  setInfo("points", info.stats.points);
  setInfo("ms", info.decodeMs, `${info.decodeMs.toFixed(1)} ms (${LEVEL_NAMES[info.stats.level]} level)`);
  render();
  let note = info.faceCount === 0 ? "an empty mesh: every point of the file is on one side of the surface" : "";
  if (info.stats.gaveUp) note = "the decoder dropped this file's filter (no crossing-free result)";
  setState("ready", note);
}

async function openFile(file) {
  try {
    await show(await file.arrayBuffer(), file.name, true);
  } catch (error) {
    showError(`cannot read ${file.name}: ${error.message}`);
  }
}

async function openUrl(url) {
  const name = decodeURIComponent(new URL(url, location.href).pathname.split("/").pop() || url);
  try {
    const response = await fetch(url);
    if (!response.ok) throw new Error(`HTTP ${response.status} ${response.statusText}`);
    await show(await response.arrayBuffer(), name, true);
  } catch (error) {
    showError(`cannot load ${url}: ${error.message}`);
  }
}

$("open").addEventListener("change", (event) => {
  const file = event.target.files[0];
  event.target.value = ""; // the same file again is a change too
  if (file) openFile(file);
});
for (const input of document.querySelectorAll('input[name="level"]')) {
  input.addEventListener("change", () => current && show(current.buffer, current.name, false));
}

let dragDepth = 0;
window.addEventListener("dragenter", (event) => {
  event.preventDefault();
  dragDepth++;
  $("drop").hidden = false;
});
window.addEventListener("dragleave", () => {
  dragDepth = Math.max(0, dragDepth - 1);
  if (dragDepth === 0) $("drop").hidden = true;
});
window.addEventListener("dragover", (event) => event.preventDefault());
window.addEventListener("drop", (event) => {
  event.preventDefault();
  dragDepth = 0;
  $("drop").hidden = true;
  const file = event.dataTransfer && event.dataTransfer.files[0];
  if (file) openFile(file);
});

const start = new URLSearchParams(location.search).get("file");
if (start) openUrl(start);
