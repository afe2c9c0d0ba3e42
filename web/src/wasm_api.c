/*
 * wasm_api.c -- the WebAssembly module's exports: tw_decode behind handles that JavaScript can hold.
 *
 * JavaScript cannot read C structs by name, so a decode's outcome lives in a tw_wasm_result allocated here and is
 * read through the accessors below (every pointer is an offset into the module's memory). The sequence, as
 * web/tetweave_decoder.mjs runs it:
 *   in = tw_wasm_malloc(size); copy the file's bytes to in;
 *   r = tw_wasm_decode(in, size, level); tw_wasm_free(in);
 *   tw_wasm_result_status(r) == 0 ? read positions / indices : read tw_wasm_result_message(r);
 *   tw_wasm_result_free(r);
 * Nothing here is global or mutable: several results may be alive at once.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../../decoder/tetweave_decoder.h"

#define TW_EXPORT(name) __attribute__((export_name(#name))) name

/* A decode's outcome: the mesh (zeroed on failure), the status and the core's one-line message. */
typedef struct tw_wasm_result {
    int status;
    tw_mesh mesh;
    char message[256];
} tw_wasm_result;

/* The module's allocator, for the input bytes: size bytes (at least 1), or 0 when memory cannot grow. */
void *TW_EXPORT(tw_wasm_malloc)(size_t size) { return malloc(size ? size : 1); }

/* Release what tw_wasm_malloc returned (0 is fine). */
void TW_EXPORT(tw_wasm_free)(void *pointer) { free(pointer); }

/*
 * Decode data[0..size) at `level` (tw_level: 0 control, 1 smoothed, 2 full) on the calling thread.
 * Returns a result to release with tw_wasm_result_free, or 0 when even the result could not be allocated (the
 * caller reports that as out of memory). A failed decode is a result with a nonzero status and its message.
 */
tw_wasm_result *TW_EXPORT(tw_wasm_decode)(const unsigned char *data, size_t size, int level) {
    tw_wasm_result *result = calloc(1, sizeof *result);
    if (!result) return 0;
    tw_decode_options options = tw_default_options();
    options.level = level;
    options.threads = 1;
    result->status = tw_decode(data, size, &options, &result->mesh, result->message, sizeof result->message);
    return result;
}

/* Release a result and its mesh (0 is fine). */
void TW_EXPORT(tw_wasm_result_free)(tw_wasm_result *result) {
    if (!result) return;
    tw_mesh_free(&result->mesh);
    free(result);
}

/* tw_status of the decode: 0 on success. */
int TW_EXPORT(tw_wasm_result_status)(const tw_wasm_result *result) { return result->status; }

/* The NUL-terminated one-line message of a failed decode ("" on success). */
const char *TW_EXPORT(tw_wasm_result_message)(const tw_wasm_result *result) { return result->message; }

/* Vertices and faces of the mesh (0 for an empty mesh or a failure). */
size_t TW_EXPORT(tw_wasm_result_vertex_count)(const tw_wasm_result *result) { return result->mesh.vertex_count; }
size_t TW_EXPORT(tw_wasm_result_face_count)(const tw_wasm_result *result) { return result->mesh.face_count; }

/* vertex_count * 3 doubles and face_count * 3 uint32 indices, owned by the result (0 when empty). */
const double *TW_EXPORT(tw_wasm_result_positions)(const tw_wasm_result *result) { return result->mesh.positions; }
const uint32_t *TW_EXPORT(tw_wasm_result_indices)(const tw_wasm_result *result) { return result->mesh.indices; }

/*
 * One field of the decode's tw_decode_stats as a double (every count fits 2^53 exactly): 0 points, 1 tets,
 * 2 extracted_faces, 3 restored, 4 gave_up, 5 level, 6 smoothing, 7 subdivision; -1 for another index.
 */
double TW_EXPORT(tw_wasm_result_stat)(const tw_wasm_result *result, int which) {
    const tw_decode_stats *s = &result->mesh.stats;
    switch (which) {
    case 0: return (double)s->points;
    case 1: return (double)s->tets;
    case 2: return (double)s->extracted_faces;
    case 3: return (double)s->restored;
    case 4: return (double)s->gave_up;
    case 5: return (double)s->level;
    case 6: return (double)s->smoothing;
    case 7: return (double)s->subdivision;
    default: return -1.0;
    }
}

/* The short constant name of a status code (tw_status_string). */
const char *TW_EXPORT(tw_wasm_status_string)(int status) { return tw_status_string(status); }

/* TW_DECODER_VERSION of the core this module was built from. */
int TW_EXPORT(tw_wasm_version)(void) { return TW_DECODER_VERSION; }
