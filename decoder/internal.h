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
    int64_t *holes;          /* hole_count strictly increasing face ranks (NULL when none, or not decoded yet) */
    size_t hole_count;
    size_t sizes[5];         /* bytes of header, positions, s, c, checksum */
} tw_file;

int tw_parse(const unsigned char *data, size_t size, tw_file *file, tw_error *err);
void tw_file_free(tw_file *file);

/* tw_parse without decoding the holes section's ranks (file->holes stays NULL): only its framing is checked where
 * tw_parse decodes it (tw_check_holes_section), so a file's errors keep their class and, but for the stream's own,
 * their order; the decoder reads the ranks after marching tets with tw_file_decode_holes, bounded by the surface's
 * face count F0 rather than by 64 N (2^28 ranks for a hostile file of 2^22 points). */
int tw_parse_deferred(const unsigned char *data, size_t size, tw_file *file, tw_error *err);
/* Whether `file` (from tw_parse_deferred) has a holes section whose ranks are not decoded yet. */
int tw_file_holes_pending(const tw_file *file);
/* The pending ranks of `file` from the same `data` / `size` (the section is the bytes between the c section and
 * the checksum), K <= max_faces (0: no bound but 64 N): file->holes and hole_count set. A file without pending
 * ranks: TW_OK, nothing done. */
int tw_file_decode_holes(const unsigned char *data, size_t size, tw_file *file, uint64_t max_faces, tw_error *err);

/* ---- positions, s prediction, dequantization (octree.c, predict.c, dequantize.c; container.c: tw_parse) ---- */

/* The positions section (formats/octree.py decode; formats/README.md "Positions section" and "...,
 * context-coded"): `size` bytes of models and words, b = bits (6..16), n >= 1 points expected, contexts = flags
 * bit 2. cells: n * 3 int32 out, the leaves in canonical (Morton) order. TW_ERROR_INVALID for a malformed
 * section (models short or bad, words not a multiple of 4, a level with more than n children, not n leaves),
 * TW_ERROR_MEMORY. Allocates O(n) working memory, never more than the n the header announced. */
int tw_decode_octree(const unsigned char *section, size_t size, int bits, uint32_t n, int contexts, int32_t *cells,
                     tw_error *err);

/* formats/quantize.py's dequantizers, binary64 with one rounding per operation as written:
 * positions x = ((2k + 1 - 2^b) * 1.2) / 2^b (n * 3 values); s = (k + 0.5) * step; c_j = k_j * c_steps[floor(sqrt j)]
 * (n * q values, row-major). */
void tw_dequantize_positions(const int32_t *cells, size_t n, int bits, double *points);
void tw_dequantize_s(const int32_t *k, size_t n, double step, double *s);
void tw_dequantize_c(const int32_t *k, size_t n, int sh_degree, const double *band_steps, double *c);

/* The s prediction (formats/predict.py; formats/README.md "s section, predicted"). */
#define TW_PREDICT_K 8                       /* neighbours per point (K_NEIGHBORS) */
#define TW_PREDICT_MAX_K 64                  /* largest k the kernels accept */
#define TW_PREDICT_COORD_BITS 16             /* cells below 2^16 per axis */
#define TW_PREDICT_BOUND_RANK 4096           /* QUERY_WIDTHS[-1] */
#define TW_PREDICT_MAX_CANDIDATES (1 << 16)  /* GRID_MAX_CANDIDATES: the grid search's work bound per level */
#define TW_PREDICT_RIDGE 0.1                 /* RIDGE_ABSOLUTE */
#define TW_PREDICT_RESIDUAL_BOUND ((int64_t)1 << 40) /* _RESIDUAL_BOUND */
#define TW_PREDICT_SYMBOL_LIMIT ((int64_t)1 << 20)   /* s symbols lie in [-2^20, 2^20 - 1] */

/* Morton code of a cell (x, y, z < 2^16; quantize.morton_keys). */
uint64_t tw_morton_key(uint64_t x, uint64_t y, uint64_t z);
/* predict._first_level: the finest level whose occupied cells hold 4 points on average (or one cell). */
int tw_predict_first_level(const int64_t *morton, int64_t n);

/* The causal neighbour search of predict.causal_neighbors (row kernels shared with formats/_native.c).
 * begin: cells (n * 3 int64, each in [0, 2^16)) with their Morton codes (n, strictly ascending), k neighbours
 * (1..TW_PREDICT_MAX_K), the bound rank (QUERY_WIDTHS[-1]), the first level (0..16) and the work cap (candidates
 * per level). TW_OK, TW_ERROR_ARGUMENT (a parameter or cell out of range, cells not in canonical order) or
 * TW_ERROR_MEMORY; the arrays must outlive the search. row: rows i in ascending order; writes idx[0..k) (-1 where
 * missing) and d2[0..k) (0 there) sorted by (d2, index) and returns 0, or returns 1 when the point's block exceeds
 * the cap (nothing written: the caller's fallback answers it), or -TW_ERROR_MEMORY. */
typedef struct tw_neighbor_search tw_neighbor_search;
int tw_neighbors_begin(tw_neighbor_search **search, const int64_t *cells, const int64_t *morton, int64_t n,
                       int64_t k, int64_t bound_rank, int first_level, int64_t cap);
int tw_neighbors_row(tw_neighbor_search *search, int64_t i, int64_t *idx, int64_t *d2);
void tw_neighbors_end(tw_neighbor_search *search);

/* The exact answer for the rows over the work cap (predict._tree_rows: the k nearest earlier points among those
 * closer than the bound_rank-th nearest point), by a bounding-box hierarchy over the Morton-ordered cells (the
 * same cells as the search, which checked them). O(bound_rank log bound_rank) per query on any point set. */
typedef struct tw_point_tree tw_point_tree;
int tw_point_tree_build(tw_point_tree **tree, const int64_t *cells, int64_t n);
int tw_point_tree_neighbors(tw_point_tree *tree, int64_t i, int64_t k, int64_t bound_rank, int64_t *idx,
                            int64_t *d2); /* TW_OK, TW_ERROR_ARGUMENT, TW_ERROR_MEMORY */
void tw_point_tree_free(tw_point_tree *tree);

/* predict.predictor_weights of one row: beta[0..k) from the row's neighbours idx / d2 (ridge factor
 * TW_PREDICT_RIDGE). 0, or -1 for a neighbour index outside [-1, n) or a distance <= 0 (nothing meaningful). */
int tw_predict_weights_row(const int64_t *cells, int64_t n, int64_t i, const int64_t *idx, const int64_t *d2,
                           int64_t k, double ridge_factor, double *beta);
/* One step of the sequential pass: a = sum of beta * u over the row's slots in order (u of earlier points),
 * *sym = floor(clamp(a, lo, hi)) + clamp(residual, +-bound); *sum (if not NULL) receives a. 0; 1 when a is NaN;
 * 2 when a neighbour index is not an earlier point (outside [-1, i)). */
int tw_predict_symbol(int64_t i, const int64_t *idx, const double *beta, int64_t k, const double *u, double lo,
                      double hi, int64_t residual, int64_t bound, int64_t *sym, double *sum);

/* The decoder core's whole prediction: cells (n * 3 int32, the octree's leaves) and the residuals of the s
 * section (tw_decode_s_residuals) -> the s symbols (n int32). TW_ERROR_INVALID for a symbol outside
 * [-2^20, 2^20) (attributes.decode_s_predicted's check), TW_ERROR_MEMORY; O(n) memory. */
int tw_predict_s(const int32_t *cells, size_t n, const int32_t *residual, int32_t *symbols, tw_error *err);

/* ---- surfaces -------------------------------------------------------------------------------------------- */

/* A triangle mesh owned by the core: vertices v (nv * 3 doubles), faces f (nf * 3 int32). */
typedef struct tw_surface {
    size_t nv, nf;
    double *v;
    int32_t *f;
} tw_surface;

void tw_surface_free(tw_surface *surface);

/* ---- range coder (range.c) and the s, c and holes sections (attributes.c, holes_section.c) ---------------- */
/* formats/README.md, "Entropy coder", specifies the decoder these functions implement; every function returns
 * TW_OK or a tw_status set through tw_fail (a stream that does not decode is TW_ERROR_INVALID). */

#define TW_RANGE_PRECISION 24            /* probabilities in units of 2^-24 */
#define TW_MODEL_MAX_SYMBOLS 255         /* largest alphabet of a model (a stored histogram has <= 255 bytes) */

/* A range decoder over little-endian uint32 words (any alignment); words past the end read as zero. */
typedef struct tw_range {
    const unsigned char *words; /* word i is bytes [4i, 4i + 4) */
    size_t word_count;
    size_t next;                /* the next word to read */
    uint64_t lower, range, point;
    const char *what;           /* the stream's name in messages ("s", "c", "holes", "positions") */
} tw_range;

/* A categorical model over symbols 0..size-1: symbol i covers quantiles [cum[i], cum[i + 1]), cum[0] = 0,
 * cum[size] = 2^24, strictly increasing (every symbol has probability >= 2^-24). */
typedef struct tw_model {
    int size;
    uint32_t cum[TW_MODEL_MAX_SYMBOLS + 1];
} tw_model;

/* Start a decoder on word_count words at `words` (reads the first two). */
void tw_range_start(tw_range *rc, const unsigned char *words, size_t word_count, const char *what);
/* Start a decoder on a section's word part of `size` bytes; TW_ERROR_INVALID unless size is a multiple of 4. */
int tw_range_open(tw_range *rc, const unsigned char *bytes, size_t size, const char *what, tw_error *err);

/* Models from integer weights w (a of them, 2..255, each >= 0, sum 2^24 - a), from a stored uint8 histogram
 * (formats/entropy.py histogram_weights), from a binary-model byte v (1..255: P(1) = v / 256), and the uniform
 * model over a symbols. A bad model is TW_ERROR_INVALID. */
int tw_model_weights(tw_model *m, const int64_t *w, size_t a, tw_error *err);
int tw_model_histogram(tw_model *m, const unsigned char *v, size_t a, tw_error *err);
int tw_model_binary(tw_model *m, int v, tw_error *err);
int tw_model_uniform(tw_model *m, size_t a, tw_error *err);

/* One symbol with model m; one bit with the binary model of byte v (1..255; 128 is the fair bit). */
int tw_range_decode(tw_range *rc, const tw_model *m, int *symbol, tw_error *err);
int tw_range_decode_bit(tw_range *rc, int v, int *bit, tw_error *err);
/* `count` symbols of model m, or bits of binary model v, into out[0..count). */
int tw_range_decode_symbols(tw_range *rc, const tw_model *m, size_t count, uint8_t *out, tw_error *err);
int tw_range_decode_bits(tw_range *rc, int v, size_t count, uint8_t *out, tw_error *err);
/* Raw bits (entropy.Reader.decode_raw): values[i] gets nbits[i] (0..32) fair bits, most significant first, coded
 * by bit plane: plane p = max(nbits) - 1 .. 0 codes bit p of every i with nbits[i] > p, in index order. */
int tw_range_decode_raw(tw_range *rc, const uint8_t *nbits, size_t count, uint32_t *values, tw_error *err);
/* Grouped by context (entropy.Reader.decode_grouped): the symbols with ctx[i] == 0 in index order with
 * models[0], then ctx 1 with models[1], ...; an i whose ctx is >= model_count is not coded and gets 0. */
int tw_range_decode_grouped(tw_range *rc, const uint8_t *ctx, size_t count, const tw_model *models,
                            int model_count, uint8_t *out, tw_error *err);

/* A cursor over the model bytes at the start of a section (formats/attributes.py _Models): take `count` bytes
 * (TW_ERROR_INVALID "the <what> models are truncated" past the end), or one stored histogram (a length byte A in
 * 2..max_alphabet, then A bytes) as a model. */
typedef struct tw_models {
    const unsigned char *data;
    size_t size, pos;
    const char *what;
} tw_models;
int tw_models_take(tw_models *c, size_t count, const unsigned char **bytes, tw_error *err);
int tw_models_histogram(tw_models *c, size_t max_alphabet, tw_model *m, tw_error *err);

/* The s section, flags bit 1 = 0 (formats/attributes.py decode_s): k[0..n) the s symbols, in [-2^20, 2^20). */
int tw_decode_s(const unsigned char *section, size_t size, uint32_t n, int32_t *k, tw_error *err);
/* The s section, flags bit 1 = 1: the residuals r[0..n) (|r| < 2^22) of "s section, predicted"; predict.c turns
 * them into symbols (formats/attributes.py decode_s_predicted = these residuals, then predict.reconstruct and its
 * range check). n = 0 needs an empty section. */
int tw_decode_s_residuals(const unsigned char *section, size_t size, uint32_t n, int32_t *r, tw_error *err);
/* The c section (decode_c): k[0..n*q) row-major (n, q), q = (sh_degree + 1)^2, each |k| <= 2^15.
 * n = 0 or q = 0 needs an empty section (k may then be NULL). */
int tw_decode_c(const unsigned char *section, size_t size, uint32_t n, int sh_degree, int32_t *k, tw_error *err);
/* The holes section (formats/holes.py decode_holes) of a file of n points: *ranks receives a malloc'ed array of
 * *count (1..64 * max(n, 1)) strictly increasing face ranks < 2^32 (the caller frees it); NULL / 0 on failure. */
int tw_decode_holes(const unsigned char *section, size_t size, uint32_t n, int64_t **ranks, size_t *count,
                    tw_error *err);
/* The same with K also bounded by max_faces when it is not 0: the extracted surface's face count F0, which bounds
 * K (every rank is < F0) and so the allocation by the decoder's own surface rather than by 64 N (up to 2^28 faces,
 * 14 bytes each, for a hostile file of 2^22 points). */
int tw_decode_holes_bounded(const unsigned char *section, size_t size, uint32_t n, uint64_t max_faces,
                            int64_t **ranks, size_t *count, tw_error *err);
/* The holes section's framing alone (K in 1..64 max(n, 1), the histogram, whole words), allocating nothing. */
int tw_check_holes_section(const unsigned char *section, size_t size, uint32_t n, tw_error *err);


/* ---- filter: crossing checks, Taubin, creases, Loop, restores, holes (intersect.c, filter.c, loop.c, holes.c) - */

/* Crossing checks (intersect.c; geometry/intersections.py self_intersecting_faces is the reference). v: nv * 3
 * doubles; f: nf * 3 indices; only: nf bytes (nonzero = marked: only pairs with a marked face are tested; NULL in
 * tw_self_intersecting = every face); flags: nf bytes out (1 = the face crosses or touches another). threads: 1 =
 * the calling thread, more = that many pthreads (the same flags on any count; none without pthreads). */
int tw_crossings_grid(const double *v, size_t nv, const int32_t *f, size_t nf, const uint8_t *only, int threads,
                      uint8_t *flags); /* 0 done, 1 no feasible grid, -1 out of memory; indices trusted */
int tw_crossings_marked(const double *v, size_t nv, const int32_t *f, size_t nf, const uint8_t *only, int threads,
                        uint8_t *flags); /* 0 decided, 2 undecided (flags 0), -1 out of memory; indices trusted */
int tw_crossings_stars(const double *v, size_t nv, const int32_t *f, size_t nf, const uint8_t *only, int children,
                       int threads, uint8_t *flags); /* as marked; children 1 or 4 (runs of Loop children) */
int tw_self_intersecting(const double *v, size_t nv, const int32_t *f, size_t nf, const uint8_t *only, int children,
                         int threads, uint8_t *flags); /* 0 done, 1 no feasible grid, -1 memory, -2 bad index */
/* Crossing checks kept across restore rounds (intersect.c): tw_self_intersecting_kept gives tw_self_intersecting's
 * status and flags, reusing the last call's boxes, cell size, count and cell lists where it proves them unchanged
 * (checks that mark few faces). st: from tw_check_state_new (NULL: tw_self_intersecting); changed: NULL, or nf
 * bytes, nonzero for each face with a vertex moved since the last call with st (same f, nf, nv, and f's contents
 * unchanged; otherwise the state is computed afresh). tw_check_state_new: NULL when out of memory. */
#define TW_CHECK_STATE 1
typedef struct tw_check_state tw_check_state;
tw_check_state *tw_check_state_new(void);
void tw_check_state_free(tw_check_state *st);
int tw_self_intersecting_kept(tw_check_state *st, const double *v, size_t nv, const int32_t *f, size_t nf,
                              const uint8_t *only, const uint8_t *changed, int children, int threads, uint8_t *flags);

/* Taubin, creases (filter.c; geometry/smoothing.py). rows: ne directed edges (a, b) as 2 * ne int32. */
#define TW_TAUBIN_LAMBDA 0.5
#define TW_TAUBIN_MU (-0.53)
#define TW_CREASE_COS 0.8660254037844387
#define TW_MAX_CHECKS 16
/* `steps` Taubin steps of v (nv * 3, in place) over the directed rows (sorted by (a, b): smoothing.taubin's
 * neighbour order). 0, or -1 out of memory (v unchanged). Indices trusted. */
int tw_taubin(double *v, size_t nv, const int32_t *rows, size_t ne, int steps, double lam, double mu);

/* The half-edges of a closed, consistently oriented 2-manifold, sorted by (a, b) (smoothing.mesh_edges(f, nv,
 * closed=True)): *rows (2 * 3nf int32, malloc'd) and, per row, its face (*face_of, 3nf int32) and its twin's row
 * (*twin, 3nf int32); NULL for any not wanted. 0; 1 when the faces are not such a manifold (or an index is out of
 * range), -1 out of memory (nothing allocated on failure). */
int tw_half_edges(const int32_t *f, size_t nf, size_t nv, int32_t **rows, int32_t **face_of, int32_t **twin);

/* smoothing.crease_edges of a closed manifold: sharp (3nf bytes) per row of tw_half_edges. 0, or -1 memory. */
int tw_crease_rows(const double *v, const int32_t *f, size_t nf, const int32_t *face_of, const int32_t *twin,
                   double cosine, uint8_t *sharp);

/* One Loop level of v and one midpoint level of r on the same faces (subdivision.py loop_level / _apply_level; a
 * closed manifold). rows: tw_half_edges(f) (checked again here); crease: NULL (Loop's rules) or one byte per
 * undirected edge (ascending (a, b), a < b: subdivision's edge order), the crease rules. out_v, out_r:
 * (nv + 3nf/2) * 3 doubles; out_f: 4nf * 3 int32; out_ends: NULL, or 2 * 3nf/2 int32, each edge's ends (a < b).
 * r may be NULL (no reference; out_r is then not written).
 * 0; 1 not a closed manifold (nothing meaningful written); -1 out of memory. */
int tw_loop_level(const double *v, const double *r, size_t nv, const int32_t *f, size_t nf, const int32_t *rows,
                  const uint8_t *crease, double *out_v, double *out_r, int32_t *out_f, int32_t *out_ends);
/* subdivision._child_creases: the next level's creases (nh / 2 bytes, ascending edges) from its sorted rows (nh)
 * and the last level's vertex count, edge ends (out_ends of tw_loop_level), edge count and creases. */
void tw_child_creases(const int32_t *rows, size_t nh, size_t parent_nv, const int32_t *parent_ends, size_t parent_ne,
                      const uint8_t *parent_crease, uint8_t *out);

/* surface_filter.filter_surface: `smoothing` Taubin steps and `subdivision` Loop levels of the control surface
 * (crease rules with `creases`), the output transform v * scale + offset (offset NULL: none), and the restore
 * rounds of restore_crossings (at most TW_MAX_CHECKS checks; else the filter is dropped: *gave_up = 1, *restored
 * = nv). out: a new surface (free with tw_surface_free). Errors: TW_ERROR_LIMIT (more than TW_MAX_FACES faces
 * after subdivision), TW_ERROR_INVALID (the unfiltered surface crosses or touches itself, or cannot be checked),
 * TW_ERROR_INTERNAL (not a closed, consistently oriented 2-manifold), TW_ERROR_MEMORY, TW_ERROR_ARGUMENT. */
int tw_filter_surface(const tw_surface *control, int smoothing, int subdivision, int creases, double scale,
                      const double offset[3], int threads, tw_surface *out, uint64_t *restored, int *gave_up,
                      tw_error *err);

/* holes.open_holes: remove the extracted faces whose canonical ranks are `ranks` (count of them, any order, each
 * < extracted_count, else TW_ERROR_INVALID) with their `children` faces each from `closed` (closed->nf must be
 * extracted_count * children: else TW_ERROR_ARGUMENT), keeping the used vertices in order. TW_ERROR_INVALID when
 * a vertex of the extracted surface is left with two or more fans. out: a new surface. */
int tw_open_holes(const tw_surface *closed, const int32_t *extracted, size_t extracted_count, const int64_t *ranks,
                  size_t count, size_t children, tw_surface *out, tw_error *err);
/* holes.face_ranks: rank (nf int64) of each face in the canonical order (sorted corners, lexicographic). */
int tw_face_ranks(const int32_t *f, size_t nf, int64_t *ranks);

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

/* Marching tets' case tables, derived (marching.c): per case code, its active local edges in order (act, n_act),
 * the position of each local edge among them (pos, -1: inactive) and its triangles as local edges (tri, n_tri). */
typedef struct tw_mt_tables {
    int n_act[16], act[16][6], pos[16][6], n_tri[16], tri[16][2][3];
} tw_mt_tables;

/* Marching tets' integer topology: nu unique active edges (lo[k] < hi[k], sorted by (lo, hi)), nf faces (nf * 3
 * indices into the edges: per mixed tet in order, its table triangles in order) and the tet of each face. */
typedef struct tw_mt_topo {
    size_t nu, nf;
    uint32_t *lo, *hi;
    int32_t *faces;
    int32_t *face_tets;
} tw_mt_topo;

/* The format's tanh (geometry/tanh.py): the same bits on every IEEE 754 platform, within 2 ulp of tanh. */
double tw_tanh(double x);
/* Derive tables from active (16 x 6, nonzero = active) and triangle (16 x 2 x 3 local edges, -1 none) int64
 * arrays; TW_ERROR_ARGUMENT for an entry out of range or a triangle on an inactive edge. */
int tw_mt_tables_init(tw_mt_tables *tables, const int64_t *active, const int64_t *triangle, tw_error *err);
/* Topology of nt tets (nt * 4 indices < n, else TW_ERROR_ARGUMENT) for inside (n bytes, nonzero = s < 0).
 * TW_ERROR_LIMIT: n > 2^31 or 2^32 active edge occurrences; TW_ERROR_MEMORY. Free with tw_mt_topology_free. */
int tw_mt_topology(const int32_t *tets, size_t nt, const uint8_t *inside, size_t n, const tw_mt_tables *tables,
                   tw_mt_topo *out, tw_error *err);
void tw_mt_topology_free(tw_mt_topo *topo);
/* marching_tets.check_manifold: *defect 0 ok, 1 degenerate triangle, 2 directed edge used twice, 3 (closed) edge
 * without its twin. Indices >= nv or nv > 2^31: TW_ERROR_ARGUMENT. */
int tw_manifold_defect(const int32_t *faces, size_t nf, size_t nv, int closed, int *defect, tw_error *err);
/* The control surface (marching_tets_numpy(points, tz->tets, s, c, tz->hull) bit for bit): points n * 3, s n,
 * c n * (sh_degree + 1)^2 (NULL when sh_degree is -1). out: a new surface (empty when s has one sign), closed,
 * checked by tw_manifold_defect (a defect: TW_ERROR_INTERNAL with check_manifold's message). */
int tw_marching_tets(const double *points, const double *s, const double *c, int sh_degree, size_t n,
                     const tw_tets *tz, tw_surface *out, tw_error *err);

/* ---- the whole decode (decode.c) ------------------------------------------------------------------------- */

/* Everything a decode made, for the Python binding (decoder.decode_detailed): the parsed file, the control surface
 * (its faces are what a holes section's ranks name), the closed surface at the level in the output frame, and the
 * mesh with the holes opened (empty when the file has no holes section: the closed surface is the mesh). */
typedef struct tw_decode_detail {
    tw_file file;
    tw_surface control;
    tw_surface closed;
    tw_surface mesh;
    tw_decode_stats stats;
} tw_decode_detail;

/* tw_decode's stages, keeping what they made. options: not NULL, checked by the caller. On failure everything is
 * freed; on success release with tw_decode_detail_free. */
int tw_decode_detailed(const unsigned char *data, size_t size, const tw_decode_options *options,
                       tw_decode_detail *detail, tw_error *err);
void tw_decode_detail_free(tw_decode_detail *detail);
/* The decoded mesh of a detail: the opened mesh with a holes section, else the closed surface. */
const tw_surface *tw_decoded_mesh(const tw_decode_detail *detail);

#endif /* TETWEAVE_INTERNAL_H */
