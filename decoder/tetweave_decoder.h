/*
 * tetweave_decoder.h -- the TetWeave (.tw) decoder core: file bytes in, a closed triangle mesh out.
 *
 * C99, no third-party code, no Python.h. The same sources build the Python extension
 * (tetweave_codec/_decoder_native.c, a binding apart), the command line (through Python) and the WebAssembly
 * module (web/). Compile without floating-point contraction (-ffp-contract=off) and without -ffast-math: every
 * double of the output is then the same on every platform (native, wasm32) and equal to the Python reference
 * decoder's (tetweave_codec/decoder.py with TETWEAVE_CORE=0).
 *
 * The format is specified in formats/README.md; this core decodes every file the current encoder writes
 * (container version 2 with the exact Delaunay, byte 12 bit 6). Files of earlier encoders (version 1, or version 2
 * triangulated by TetGen or Qhull) are refused with TW_ERROR_UNSUPPORTED; the Python package decodes those.
 *
 * Untrusted input: every function here is safe on arbitrary bytes. A malformed, truncated or corrupted file
 * returns an error code and a one-line message, never reads outside `data[0..size)`, and every allocation is
 * checked (a failed one is TW_ERROR_MEMORY). Limits (formats/README.md, "Decoder limits"):
 *   - N <= 2^22 declared points; the parse allocates at most (52 + 12 q) N bytes, q = (d + 1)^2, after the header
 *     and CRC are valid (~1 GiB of address space at N = 2^22, d = 3, touched only as the sections decode);
 *   - the exact Delaunay and marching tets: O(N), ~1 KB per point measured;
 *   - a holes section lists K <= min(64 N, F0) faces, F0 the extracted surface's: its ranks are decoded after
 *     marching tets and K > F0 is refused before they are allocated;
 *   - decoded faces <= TW_MAX_FACES (2^26; a file that would exceed it is TW_ERROR_LIMIT, refused before Loop);
 *     the filter and its crossing checks take ~0.5 KB per face they handle (1.8 GiB for a 15.5 KB hostile file
 *     subdivided to 4 M faces; tens of GiB at the cap). A caller decoding untrusted files should cap the process's
 *     memory (RLIMIT_AS, a wasm32 heap): such files then end in TW_ERROR_MEMORY.
 *   The largest committed file (38 KB, 328 K faces) decodes in a peak RSS of 47 MiB.
 *
 * Threads: `threads` (tw_decode_options) only splits the self-intersection checks; the output is the same bytes on
 * any count. A build without pthreads (wasm32, or -DTW_NO_THREADS) runs them on the calling thread.
 */
#ifndef TETWEAVE_DECODER_H
#define TETWEAVE_DECODER_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define TW_DECODER_VERSION 1

/* Faces of a decoded mesh are at most this many (2^26, the Python decoder's MAX_SUBDIVIDED_FACES). */
#define TW_MAX_FACES (1u << 26)

/* Decode levels (formats/README.md, "Decode levels"): a decoder may stop early. */
typedef enum tw_level {
    TW_LEVEL_CONTROL = 0,  /* the marching-tets surface, before any filter */
    TW_LEVEL_SMOOTHED = 1, /* the file's Taubin steps, without its Loop levels */
    TW_LEVEL_FULL = 2      /* the file's whole filter (the default) */
} tw_level;

/* Status codes. 0 is success; every other value comes with a message. */
typedef enum tw_status {
    TW_OK = 0,
    TW_ERROR_INVALID = 1,     /* malformed, truncated or corrupted file (the Python decoder's ContainerError) */
    TW_ERROR_UNSUPPORTED = 2, /* a valid file of an earlier encoder this core does not decode (v1, TetGen, Qhull) */
    TW_ERROR_LIMIT = 3,       /* the decoded mesh would exceed TW_MAX_FACES */
    TW_ERROR_MEMORY = 4,      /* an allocation failed */
    TW_ERROR_ARGUMENT = 5,    /* a bad argument (NULL pointer, unknown level, negative threads) */
    TW_ERROR_INTERNAL = 6     /* an internal consistency check failed (the Python decoder's TopologyError) */
} tw_status;

/* Options of tw_decode. Zero-initialised is not the default: use tw_default_options(). */
typedef struct tw_decode_options {
    int level;   /* tw_level; default TW_LEVEL_FULL */
    int threads; /* threads of the crossing checks: 1 = the calling thread (default); >= 2 that many */
} tw_decode_options;

/* What a decode did, besides the mesh (all counts of this decode). */
typedef struct tw_decode_stats {
    uint32_t points;          /* N, the file's points */
    uint64_t tets;            /* tets of the Delaunay tetrahedralization */
    uint64_t extracted_faces; /* faces of the marching-tets surface (what a holes section's ranks name) */
    uint64_t restored;        /* vertices the crossing checks put back to their unfiltered place */
    int gave_up;              /* 1 when the filter was dropped (no settled result within the checks' budget) */
    int level;                /* the level decoded */
    int smoothing;            /* Taubin steps applied at that level */
    int subdivision;          /* Loop levels applied at that level */
} tw_decode_stats;

/* A decoded mesh. positions: vertex_count * 3 doubles (x, y, z) in the input mesh's frame; indices:
 * face_count * 3 vertex indices, counter-clockwise seen from outside. Owned by the core: release with
 * tw_mesh_free. An empty mesh (all s of one sign) has counts 0 and NULL arrays. */
typedef struct tw_mesh {
    size_t vertex_count;
    size_t face_count;
    double *positions;
    uint32_t *indices;
    tw_decode_stats stats;
} tw_mesh;

/* The defaults: level TW_LEVEL_FULL, threads 1. */
tw_decode_options tw_default_options(void);

/*
 * Decode a .tw file.
 *   data, size: the file's bytes (data may be NULL when size is 0; that is TW_ERROR_INVALID).
 *   options:    NULL for tw_default_options().
 *   mesh:       receives the mesh; on failure it is zeroed (nothing to free).
 *   message, message_size: a buffer for a one-line, NUL-terminated message on failure (may be NULL / 0); it is
 *               set to "" on success.
 * Returns TW_OK or a tw_status. Safe on untrusted input (see the top of this file).
 */
int tw_decode(const unsigned char *data, size_t size, const tw_decode_options *options, tw_mesh *mesh,
              char *message, size_t message_size);

/* Release a mesh returned by tw_decode (NULL or a zeroed mesh is fine). */
void tw_mesh_free(tw_mesh *mesh);

/* A short constant name of a status code ("ok", "invalid file", ...). */
const char *tw_status_string(int status);

#ifdef __cplusplus
}
#endif

#endif /* TETWEAVE_DECODER_H */
