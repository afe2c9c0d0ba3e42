// Types of tetweave_decoder.mjs: the TetWeave (.tw) decoder, the C core compiled to WebAssembly.

/** Decode levels of the format: the marching-tets surface, its Taubin smoothing, or the file's whole filter. */
export type Level = "control" | "smoothed" | "full" | 0 | 1 | 2;

export declare const LEVELS: Readonly<{ control: 0; smoothed: 1; full: 2 }>;

/** What a decode did besides the mesh (tw_decode_stats of decoder/tetweave_decoder.h). */
export interface DecodeStats {
  points: number;
  tets: number;
  extractedFaces: number;
  restored: number;
  gaveUp: boolean;
  level: number;
  smoothing: number;
  subdivision: number;
}

export interface DecodeOptions<P extends "float32" | "float64" = "float32" | "float64"> {
  /** Default "full". */
  level?: Level;
  /** "float32" (default) or "float64": the doubles the Python decoder returns, bit for bit. */
  precision?: P;
}

export interface DecodedMesh<T extends Float32Array | Float64Array = Float32Array | Float64Array> {
  /** x, y, z per vertex, in the input mesh's frame. */
  positions: T;
  /** Three vertex indices per face, counter-clockwise seen from outside. */
  indices: Uint32Array;
  vertexCount: number;
  faceCount: number;
  stats: DecodeStats;
}

/** The Error thrown for a file the core refuses: message is the core's one-line message. */
export interface DecodeError extends Error {
  /** tw_status: 1 invalid file, 2 unsupported file, 3 mesh too large, 4 out of memory, 5 bad argument, 6 internal. */
  status: number;
  /** The status's name ("invalid file", ...). */
  code: string;
}

export declare class Decoder {
  readonly module: WebAssembly.Module;
  /** TW_DECODER_VERSION of the core inside the module. */
  readonly coreVersion: number;
  decode(data: ArrayBuffer | ArrayBufferView, options: DecodeOptions<"float64"> & { precision: "float64" }): DecodedMesh<Float64Array>;
  decode(data: ArrayBuffer | ArrayBufferView, options?: DecodeOptions<"float32">): DecodedMesh<Float32Array>;
}

export interface CreateDecoderOptions {
  /** Where the module comes from: a URL or path (default: tetweave_decoder.wasm beside the module), its bytes, or a
   * compiled WebAssembly.Module. */
  wasm?: string | URL | ArrayBuffer | ArrayBufferView | WebAssembly.Module;
}

export declare function createDecoder(options?: CreateDecoderOptions): Promise<Decoder>;
