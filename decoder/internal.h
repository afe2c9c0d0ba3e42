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

#endif /* TETWEAVE_INTERNAL_H */
