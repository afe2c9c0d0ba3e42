// TWLoader.js -- a three.js loader for TetWeave (.tw) files, in the manner of DRACOLoader: the files decode in a
// small pool of Web Workers, each running the WebAssembly decoder (tetweave_decoder.mjs + .wasm), which is fetched
// and compiled once and handed to every worker.
//
//   import { TWLoader } from "tetweave-decoder/TWLoader.js";
//   const loader = new TWLoader().setDecoderPath("/decoder/"); // the folder of tetweave_decoder.mjs and .wasm
//   loader.load("mesh.tw", (geometry) => scene.add(new Mesh(geometry, material)), undefined, console.error);
//   const geometry = await loader.loadAsync("mesh.tw");
//
// The geometry has `position` (float32), `index` (uint32) and computed vertex normals; geometry.userData.tetweave
// holds the decode's counts, the core's statistics and its time in the worker (milliseconds).
import { BufferAttribute, BufferGeometry, FileLoader, Loader } from "three";

const LEVELS = ["control", "smoothed", "full"];

// The worker: a module script (blob URL) importing the decoder from the decoder path. It receives the compiled
// WebAssembly.Module once ("init"), then one message per file, and answers with the arrays (transferred).
function workerSource(decoderUrl) {
  return `import { createDecoder } from ${JSON.stringify(decoderUrl)};
let ready = null;
self.onmessage = async ({ data }) => {
  if (data.type === "init") {
    ready = createDecoder({ wasm: data.module });
    ready.catch(() => {});
    return;
  }
  const { id, buffer, level } = data;
  try {
    const decoder = await ready;
    const t0 = performance.now();
    const mesh = decoder.decode(new Uint8Array(buffer), { level });
    const ms = performance.now() - t0;
    self.postMessage({ id, mesh, ms }, [mesh.positions.buffer, mesh.indices.buffer]);
  } catch (error) {
    self.postMessage({ id, error: String(error && error.message || error), status: error && error.status });
  }
};
`;
}

export class TWLoader extends Loader {
  constructor(manager) {
    super(manager);
    this.decoderPath = new URL("./", import.meta.url).href; // this file sits beside the decoder by default
    this.workerLimit = 4;
    this.level = "full";
    this._workers = []; // { worker, pending: Map(id -> { resolve, reject }) }
    this._module = null; // Promise<WebAssembly.Module>
    this._workerUrl = null;
    this._nextId = 1;
  }

  /** The folder (URL, ending in "/") holding tetweave_decoder.mjs and tetweave_decoder.wasm. */
  setDecoderPath(path) {
    this.decoderPath = path;
    return this;
  }

  /** Workers decoding at once (default 4); files beyond that queue on the least busy worker. */
  setWorkerLimit(workerLimit) {
    this.workerLimit = workerLimit;
    return this;
  }

  /** The decode level of later loads: "control", "smoothed" or "full" (default). */
  setLevel(level) {
    if (!LEVELS.includes(level)) throw new Error(`TWLoader: unknown level ${JSON.stringify(level)}`);
    this.level = level;
    return this;
  }

  load(url, onLoad, onProgress, onError) {
    const loader = new FileLoader(this.manager);
    loader.setPath(this.path);
    loader.setResponseType("arraybuffer");
    loader.setRequestHeader(this.requestHeader);
    loader.setWithCredentials(this.withCredentials);
    const fail = (error) => {
      if (onError) onError(error);
      else console.error(error);
      this.manager.itemError(url);
    };
    loader.load(url, (buffer) => this.parse(buffer).then(onLoad).catch(fail), onProgress, fail);
  }

  /**
   * Decode a .tw file's bytes (ArrayBuffer; it is copied, not detached) into a BufferGeometry.
   * options.level overrides setLevel for this file. Rejects with the decoder's Error (message, status, code).
   */
  async parse(buffer, options = {}) {
    const { mesh, ms } = await this.decode(buffer, options);
    const geometry = new BufferGeometry();
    geometry.setAttribute("position", new BufferAttribute(mesh.positions, 3));
    geometry.setIndex(new BufferAttribute(mesh.indices, 1));
    geometry.computeVertexNormals();
    geometry.userData.tetweave = {
      vertexCount: mesh.vertexCount,
      faceCount: mesh.faceCount,
      stats: mesh.stats,
      decodeMs: ms,
      bytes: buffer.byteLength,
    };
    return geometry;
  }

  /** The worker's raw answer: { mesh: { positions, indices, vertexCount, faceCount, stats }, ms }. */
  async decode(buffer, options = {}) {
    const level = options.level ?? this.level;
    const module = await this._wasmModule();
    const id = this._nextId++;
    const copy = buffer instanceof ArrayBuffer ? buffer.slice(0) : new Uint8Array(buffer).slice().buffer;
    return new Promise((resolve, reject) => {
      // the slot is chosen and the task registered in one step: concurrent loads see each other's tasks
      const slot = this._slot(module);
      slot.pending.set(id, { resolve, reject });
      slot.worker.postMessage({ type: "decode", id, buffer: copy, level }, [copy]);
    });
  }

  _wasmModule() {
    if (this._module === null) {
      const loader = new FileLoader(this.manager);
      loader.setResponseType("arraybuffer");
      loader.setRequestHeader(this.requestHeader);
      loader.setWithCredentials(this.withCredentials);
      this._module = loader
        .loadAsync(new URL("tetweave_decoder.wasm", new URL(this.decoderPath, location.href)).href)
        .then((bytes) => WebAssembly.compile(bytes));
      this._module.catch(() => {
        this._module = null; // a failed fetch is tried again by the next load
      });
    }
    return this._module;
  }

  _slot(module) {
    if (this._workers.length < this.workerLimit) {
      const free = this._workers.find((slot) => slot.pending.size === 0);
      if (free) return free;
      return this._spawn(module);
    }
    return this._workers.reduce((best, slot) => (slot.pending.size < best.pending.size ? slot : best));
  }

  _spawn(module) {
    if (this._workerUrl === null) {
      const decoderUrl = new URL("tetweave_decoder.mjs", new URL(this.decoderPath, location.href)).href;
      const blob = new Blob([workerSource(decoderUrl)], { type: "text/javascript" });
      this._workerUrl = URL.createObjectURL(blob);
    }
    const worker = new Worker(this._workerUrl, { type: "module" });
    const slot = { worker, pending: new Map() };
    worker.onmessage = ({ data }) => {
      const task = slot.pending.get(data.id);
      if (!task) return;
      slot.pending.delete(data.id);
      if (data.error === undefined) {
        task.resolve({ mesh: data.mesh, ms: data.ms });
      } else {
        const error = new Error(data.error);
        error.status = data.status;
        task.reject(error);
      }
    };
    worker.onerror = (event) => {
      // The worker could not start (its import failed) or crashed: its files fail, the next load starts another.
      event.preventDefault?.();
      const error = new Error(`TWLoader: decoder worker failed: ${event.message || "cannot load the decoder"}`);
      for (const task of slot.pending.values()) task.reject(error);
      slot.pending.clear();
      worker.terminate();
      this._workers = this._workers.filter((other) => other !== slot);
    };
    worker.postMessage({ type: "init", module });
    this._workers.push(slot);
    return slot;
  }

  /** Stop the workers and release the worker script (a later load starts them again). */
  dispose() {
    for (const slot of this._workers) slot.worker.terminate();
    this._workers = [];
    if (this._workerUrl !== null) URL.revokeObjectURL(this._workerUrl);
    this._workerUrl = null;
    return this;
  }
}
