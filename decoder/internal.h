/*
 * internal.h -- the decoder core's stages and their contracts (not public: see tetweave_decoder.h).
 *
 * Data flow of tw_decode (decode.c):
 *   parse (container.c: envelope, header, CRC; octree.c, range.c, attributes.c, predict.c: the sections)
 *     -> tw_file (cells, dequantized points, s, c, holes)
 *   -> delaunay.c    tw_delaunay(cells)            -> tets, hull faces
 *   -> marching.c    tw_marching_tets(...)         -> tw_surface (the control surface)
 *   -> filter.c      tw_filter_surface(...)        -> tw_surface in the output frame (smoothing, Loop, restores)
 *   -> holes.c       tw_open_holes(...)            -> the mesh
 * Every stage reports failure through tw_error (status + one-line message) and returns nonzero.
 */
#ifndef TETWEAVE_INTERNAL_H
#define TETWEAVE_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "tetweave_decoder.h"

typedef struct tw_error {
    int status;          /* tw_status */
    char message[256];
} tw_error;

/* Set err (when not NULL) and return `status`; printf-style message. */
int tw_fail(tw_error *err, int status, const char *fmt, ...);

/* ---- container ------------------------------------------------------------------------------------------- */

/* A parsed version-2 file (formats/tw2.py TetWeaveFileV2 and its dequantized arrays). */
typedef struct tw_file {
    int version;             /* 2 */
    int flags;               /* byte 10 */
    int sh_degree;           /* -1..3 */
    int q;                   /* (sh_degree + 1)^2 */
    int position_bits;       /* 6..16 */
    int exact;               /* byte 12 bit 6 */
    int creases;             /* byte 12 bit 7 */
    int smoothing;           /* flags bits 3-4 */
    int subdivision;         /* flags bits 5-6 */
    uint32_t n;              /* points */
    double scale;
    double offset[3];
    double s_step;
    double c_steps[4];       /* per band, sh_degree + 1 of them */
    int32_t *cells;          /* n * 3, canonical order */
    double *points;          /* n * 3, dequantized (normalized frame) */
    double *s;               /* n */
    double *c;               /* n * q (NULL when q == 0) */
    int64_t *holes;          /* hole_count strictly increasing face ranks (NULL when none) */
    size_t hole_count;
    size_t sizes[5];         /* bytes of header, positions, s, c, checksum */
} tw_file;

int tw_parse(const unsigned char *data, size_t size, tw_file *file, tw_error *err);
void tw_file_free(tw_file *file);

/* ---- surfaces -------------------------------------------------------------------------------------------- */

/* A triangle mesh owned by the core: vertices v (nv * 3 doubles), faces f (nf * 3 int32). */
typedef struct tw_surface {
    size_t nv, nf;
    double *v;
    int32_t *f;
} tw_surface;

void tw_surface_free(tw_surface *surface);

/* ---- exact Delaunay and marching tets (delaunay.c, marching.c) ------------------------------------------- */

/* The exact Delaunay's tets and hull faces (formats/README.md, "The exact Delaunay"): tets nt * 4 and hull
 * nh * 3 int32 indices into the caller's cells, positively oriented / outward, in the canonical order; both NULL
 * and 0 when there are fewer than 4 distinct or only coplanar points. Release with tw_tets_free. */
typedef struct tw_tets {
    size_t nt, nh;
    int32_t *tets;
    int32_t *hull;
} tw_tets;

#define TW_DELAUNAY_MAX_BITS 23         /* cell coordinates in [0, 2^23 - 1] */
#define TW_DELAUNAY_MAX_POINTS (1 << 26)

/* Tetrahedralize n cells (n * 3 int32, any integers in [0, 2^23)); duplicates: only the lowest index is a vertex.
 * A file's grid cells (b bits) give the same arrays as their lattice points (tw_snap_to_lattice of the dequantized
 * points, k -> k 2^(23-b) + 2^(22-b): one uniform scale and a translation, which keep every predicate's sign and
 * every rank). Errors: TW_ERROR_ARGUMENT
 * (coordinates out of range, n > 2^26), TW_ERROR_MEMORY, TW_ERROR_LIMIT (a degenerate set needing more than
 * max(64 n + 4096, 2^22) tets), TW_ERROR_INTERNAL ("flat tet ...", "walk ..."; never expected). */
int tw_delaunay(const int32_t *cells, size_t n, tw_tets *out, tw_error *err);
void tw_tets_free(tw_tets *tz);
/* geometry/delaunay.py snap_to_lattice: n float points (n * 3 doubles, finite) -> cells (n * 3 int32). */
int tw_snap_to_lattice(const double *points, size_t n, int32_t *cells, tw_error *err);

#endif /* TETWEAVE_INTERNAL_H */
