// tetweave_decoder.mjs -- the TetWeave (.tw) decoder as an ES module: the C core (decoder/) compiled to
// WebAssembly (tetweave_decoder.wasm, built by web/build.py), no dependencies, the same in node and in browsers.
//
//   import { createDecoder } from "tetweave-decoder";
//   const decoder = await createDecoder();
//   const { positions, indices } = decoder.decode(bytes, { level: "full" });
//
// positions are the vertices' x, y, z (Float32Array, or Float64Array with precision: "float64": then every value
// is the double the Python decoder returns), indices three per face, counter-clockwise seen from outside.
// A file the core refuses throws an Error with the core's one-line message (error.status: the tw_status code,
// error.code: its name).

/** Decode levels of the format (formats/README.md, "Decode levels"). */
export const LEVELS = Object.freeze({ control: 0, smoothed: 1, full: 2 });

const STAT_NAMES = ["points", "tets", "extractedFaces", "restored", "gaveUp", "level", "smoothing", "subdivision"];
const STATUS_MEMORY = 4; // TW_ERROR_MEMORY
const STATUS_ARGUMENT = 5; // TW_ERROR_ARGUMENT
const isNode = typeof process !== "undefined" && process.versions != null && process.versions.node != null;

function levelNumber(level) {
  if (level === undefined || level === null) return LEVELS.full;
  if (typeof level === "string" && Object.prototype.hasOwnProperty.call(LEVELS, level)) return LEVELS[level];
  if (Number.isInteger(level) && level >= 0 && level <= 2) return level;
  throw decodeError(STATUS_ARGUMENT, `unknown level ${JSON.stringify(level)} (control, smoothed or full)`);
}

function decodeError(status, message) {
  const error = new Error(message);
  error.status = status;
  error.code = ["ok", "invalid file", "unsupported file", "mesh too large", "out of memory", "bad argument",
    "internal error"][status] ?? "unknown status";
  return error;
}

function asBytes(data) {
  if (data instanceof Uint8Array) return data;
  if (data instanceof ArrayBuffer || (typeof SharedArrayBuffer !== "undefined" && data instanceof SharedArrayBuffer)) {
    return new Uint8Array(data);
  }
  if (ArrayBuffer.isView(data)) return new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  throw decodeError(STATUS_ARGUMENT, "decode() takes the file's bytes: a Uint8Array, an ArrayBuffer or a view");
}

// The module's imports: none when built as web/build.py does (wasm32-wasi reactor, no I/O). Should a later core
// import a WASI function, each one answers ENOSYS (proc_exit throws) instead of failing to instantiate.
function importObject(module) {
  const imports = {};
  for (const { module: name, name: field, kind } of WebAssembly.Module.imports(module)) {
    if (kind !== "function") throw new Error(`tetweave_decoder.wasm imports a ${kind} ${name}.${field}`);
    imports[name] ??= {};
    imports[name][field] = field === "proc_exit"
      ? (code) => { throw new Error(`tetweave decoder exited with code ${code}`); }
      : () => 52; // __WASI_ERRNO_NOSYS
  }
  return imports;
}

async function compileFrom(source) {
  if (source instanceof WebAssembly.Module) return source;
  if (source instanceof ArrayBuffer || ArrayBuffer.isView(source)) return WebAssembly.compile(source);
  const url = source === undefined ? new URL("./tetweave_decoder.wasm", import.meta.url) : source;
  const href = String(url);
  if (isNode && (href.startsWith("file:") || !/^[a-z][a-z0-9+.-]*:/i.test(href))) {
    const { readFile } = await import("node:fs/promises");
    return WebAssembly.compile(await readFile(href.startsWith("file:") ? new URL(href) : href));
  }
  const response = await fetch(url);
  if (!response.ok) throw new Error(`tetweave decoder: cannot fetch ${href}: HTTP ${response.status}`);
  return WebAssembly.compile(await response.arrayBuffer());
}

/** The decoder over one WebAssembly instance; made by createDecoder(). Not safe to share between threads. */
export class Decoder {
  constructor(module) {
    this.module = module;
    this._exports = null;
  }

  _instance() {
    if (this._exports === null) this._start(new WebAssembly.Instance(this.module, importObject(this.module)));
    return this._exports;
  }

  _start(instance) {
    instance.exports._initialize?.(); // a WASI reactor's constructors
    this._exports = instance.exports;
  }

  /** TW_DECODER_VERSION of the C core inside the module. */
  get coreVersion() {
    return this._instance().tw_wasm_version();
  }

  /**
   * Decode the bytes of a .tw file.
   * options.level: "control", "smoothed" or "full" (default), or 0 / 1 / 2.
   * options.precision: "float32" (default) or "float64" (the doubles the Python decoder returns).
   * Returns { positions, indices, vertexCount, faceCount, stats }. Throws an Error with the core's message.
   */
  decode(data, options = {}) {
    const bytes = asBytes(data);
    const level = levelNumber(options.level);
    const precision = options.precision ?? "float32";
    if (precision !== "float32" && precision !== "float64") {
      throw decodeError(STATUS_ARGUMENT, `unknown precision ${JSON.stringify(precision)} (float32 or float64)`);
    }
    let wasm = this._instance();
    let result = 0;
    try {
      const input = wasm.tw_wasm_malloc(bytes.length);
      if (input === 0) throw decodeError(STATUS_MEMORY, `out of memory for a ${bytes.length}-byte file`);
      new Uint8Array(wasm.memory.buffer, input, bytes.length).set(bytes);
      try {
        result = wasm.tw_wasm_decode(input, bytes.length, level);
      } finally {
        wasm.tw_wasm_free(input);
      }
      if (result === 0) throw decodeError(STATUS_MEMORY, "out of memory");
      const status = wasm.tw_wasm_result_status(result);
      if (status !== 0) {
        const message = readString(wasm.memory.buffer, wasm.tw_wasm_result_message(result));
        throw decodeError(status, message || statusName(wasm, status));
      }
      return this._readMesh(wasm, result, precision);
    } catch (error) {
      if (error instanceof WebAssembly.RuntimeError) {
        // A trap (a core bug, or the stack exhausted) leaves the allocator's state unknown: start a fresh instance
        // next time rather than reuse this one. The result is lost with it.
        this._exports = null;
        result = 0;
        wasm = null;
        throw decodeError(6, `tetweave decoder crashed (${error.message}); the decoder was restarted`);
      }
      if (error instanceof RangeError && /memory/i.test(error.message)) {
        throw decodeError(STATUS_MEMORY, `out of memory (${error.message})`);
      }
      throw error;
    } finally {
      if (wasm && result) wasm.tw_wasm_result_free(result);
    }
  }

  _readMesh(wasm, result, precision) {
    const vertexCount = wasm.tw_wasm_result_vertex_count(result) >>> 0;
    const faceCount = wasm.tw_wasm_result_face_count(result) >>> 0;
    const buffer = wasm.memory.buffer; // read after the decode: the memory may have grown (a new buffer)
    const source = new Float64Array(buffer, wasm.tw_wasm_result_positions(result), vertexCount * 3);
    const positions = precision === "float64" ? source.slice() : new Float32Array(source);
    const indices = new Uint32Array(buffer, wasm.tw_wasm_result_indices(result), faceCount * 3).slice();
    const stats = {};
    STAT_NAMES.forEach((name, i) => {
      stats[name] = wasm.tw_wasm_result_stat(result, i);
    });
    stats.gaveUp = stats.gaveUp !== 0;
    return { positions, indices, vertexCount, faceCount, stats };
  }
}

function statusName(wasm, status) {
  return readString(wasm.memory.buffer, wasm.tw_wasm_status_string(status));
}

function readString(buffer, pointer) {
  const memory = new Uint8Array(buffer);
  let end = pointer;
  while (end < memory.length && memory[end] !== 0) end++;
  return new TextDecoder().decode(memory.subarray(pointer, end));
}

/**
 * Load the WebAssembly module and return a Decoder.
 * options.wasm: where the module comes from: a URL or path (default: tetweave_decoder.wasm beside this file, read
 * with fs in node and fetched in browsers), its bytes (ArrayBuffer / Uint8Array) or a compiled WebAssembly.Module
 * (what TWLoader's workers receive).
 */
export async function createDecoder(options = {}) {
  const module = await compileFrom(options.wasm);
  const decoder = new Decoder(module);
  // Instantiated now (asynchronously: browsers refuse large synchronous instantiations on their main thread), so a
  // broken module fails here, not at the first decode.
  decoder._start(await WebAssembly.instantiate(module, importObject(module)));
  return decoder;
}
