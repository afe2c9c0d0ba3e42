/*
 * container.c -- tw_parse: a `.tw` file's bytes -> tw_file (formats/README.md "Version 2": byte layout,
 * "Validation (version 2)", the sections and "Dequantization"; formats/tw.py unpack and formats/tw2.py unpack_v2
 * are the reference, whose ContainerError cases are exactly this file's TW_ERROR_INVALID cases).
 *
 * Order of the checks (the reference's, so that a damaged file reports damage rather than a strange field):
 * magic, version, size of the fixed header, SH degree, size of the whole header, announced size, CRC-32; then,
 * behind a valid checksum, the header's fields, then the sections (octree, s, c, holes), then dequantization.
 * Version 1 and version-2 files triangulated by TetGen or Qhull (byte 12 bit 6 clear) are valid files of earlier
 * encoders that this core does not decode: TW_ERROR_UNSUPPORTED once their envelope and header check out.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

#define VERSION 2
#define FIXED_SIZE 53       /* magic .. s step */
#define CHECKSUM_SIZE 4
#define MIN_FILE_SIZE 69    /* the header at SH degree -1 (65 bytes) and the checksum */
#define MAX_POINTS (1u << 22)
#define FLAG_QHULL 0x01
#define FLAG_S_PREDICTED 0x02
#define FLAG_OCTREE_CONTEXTS 0x04
#define FLAG_HOLES 0x80
#define BITS_EXACT 0x40
#define BITS_CREASES 0x80
#define MAX_SUBDIVISION 2
#define GRID_BOUND 1.2               /* quantize.GRID_BOUND */
#define MIN_SCALE 0x1p-64            /* common.MIN_SCALE */
#define MAX_SCALE 0x1p64             /* common.MAX_SCALE */
#define MAX_OFFSET_RATIO 0x1p24      /* common.MAX_OFFSET_RATIO */
#define MIN_STEP 0x1p-126            /* quantize.MIN_STEP */
#define MAX_S_STEP 1.0
#define MAX_C_STEP 4.0

static const unsigned char MAGIC[8] = {0x89, 'T', 'W', 'V', '\r', '\n', 0x1A, '\n'};

/* ------------------------------------------------------------------------------------------------------------ */
/* little-endian fields (any host byte order, any alignment) */

static uint32_t le32(const unsigned char *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static double le_f64(const unsigned char *p) {
    uint64_t bits = (uint64_t)le32(p) | (uint64_t)le32(p + 4) << 32;
    double x;
    memcpy(&x, &bits, sizeof x);
    return x;
}

static double le_f32(const unsigned char *p) { /* a float32 field widened to binary64 (exact) */
    uint32_t bits = le32(p);
    float x;
    memcpy(&x, &bits, sizeof x);
    return (double)x;
}

/*
 * crc32_zlib -- CRC-32 of data[0..size) as zlib's crc32 computes it (ISO-HDLC: reflected polynomial 0xEDB88320,
 * initial value and final XOR 0xFFFFFFFF). The byte table is built per call (256 entries: negligible next to a
 * decode) so that the core keeps no global state.
 */
static uint32_t crc32_zlib(const unsigned char *data, size_t size) {
    uint32_t table[256];
    for (uint32_t i = 0; i < 256; i++) {
        uint32_t c = i;
        for (int b = 0; b < 8; b++) c = c & 1 ? 0xEDB88320u ^ (c >> 1) : c >> 1;
        table[i] = c;
    }
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < size; i++) crc = table[(crc ^ data[i]) & 0xFF] ^ (crc >> 8);
    return crc ^ 0xFFFFFFFFu;
}

/* ------------------------------------------------------------------------------------------------------------ */
/* header checks (formats/common.py _transform_problem, quantize.step_problem) */

static int transform_problem(double scale, const double offset[3], tw_error *err) {
    if (!(isfinite(scale) && scale > 0))
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw header: scale %g (must be finite and > 0)", scale);
    for (int a = 0; a < 3; a++)
        if (!isfinite(offset[a]))
            return tw_fail(err, TW_ERROR_INVALID, "invalid .tw header: offset must be 3 finite numbers");
    for (int a = 0; a < 3; a++) {
        double reach = GRID_BOUND * scale + fabs(offset[a]);
        if (!isfinite(reach))
            return tw_fail(err, TW_ERROR_INVALID,
                           "invalid .tw header: scale %g and offset take the points beyond the float64 range", scale);
    }
    if (!(MIN_SCALE <= scale && scale <= MAX_SCALE))
        return tw_fail(err, TW_ERROR_INVALID,
                       "invalid .tw header: scale %g outside [2^-64, 2^64] (no encoder writes it)", scale);
    for (int a = 0; a < 3; a++)
        if (fabs(offset[a]) > MAX_OFFSET_RATIO * scale)
            return tw_fail(err, TW_ERROR_INVALID,
                           "invalid .tw header: offset beyond 2^24 x scale %g (the transform would round away the "
                           "decoded surface's detail)", scale);
    return TW_OK;
}

static int step_problem(const char *name, double step, double largest, tw_error *err) {
    if (!(isfinite(step) && MIN_STEP <= step && step <= largest))
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw header: %s %g (must be finite, in [2^-126, %g])", name,
                       step, largest);
    return TW_OK;
}

/* ------------------------------------------------------------------------------------------------------------ */

void tw_file_free(tw_file *file) {
    if (!file) return;
    free(file->cells);
    free(file->points);
    free(file->s);
    free(file->c);
    free(file->holes);
    memset(file, 0, sizeof *file);
}

/* The envelope and the header's fields; on success file's scalar fields are set and *sections points at the
 * first section, section_sizes[0..count) hold P, S, C (, R). */
static int parse_header(const unsigned char *data, size_t size, tw_file *file, uint32_t section_sizes[4],
                        int *with_holes, tw_error *err) {
    if (size < sizeof MAGIC) {
        if (size > 0 && memcmp(data, MAGIC, size) == 0)
            return tw_fail(err, TW_ERROR_INVALID, "truncated .tw file: %zu bytes", size);
        return tw_fail(err, TW_ERROR_INVALID, "not a .tw file (too short for the magic bytes)");
    }
    if (memcmp(data, MAGIC, sizeof MAGIC) != 0)
        return tw_fail(err, TW_ERROR_INVALID, "not a .tw file (wrong magic bytes)");
    if (size < 10) return tw_fail(err, TW_ERROR_INVALID, "truncated .tw file: %zu bytes", size);
    const unsigned version = (unsigned)data[8] | (unsigned)data[9] << 8;
    if (version == 1)
        return tw_fail(err, TW_ERROR_UNSUPPORTED,
                       "a version-1 .tw file (an earlier encoder's): the Python package tetweave_codec decodes it");
    if (version != VERSION)
        return tw_fail(err, TW_ERROR_INVALID, "unsupported .tw version %u (this decoder reads version 2)", version);
    if (size < MIN_FILE_SIZE)
        return tw_fail(err, TW_ERROR_INVALID, "truncated .tw file: %zu bytes, a version-2 header needs %d", size,
                       MIN_FILE_SIZE);
    const int flags = data[10], degree = (int)(signed char)data[11], bits_byte = data[12];
    if (degree < -1 || degree > 3)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw header: SH degree %d (expected -1..3)", degree);
    *with_holes = (flags & FLAG_HOLES) != 0;
    const int count = 3 + *with_holes;
    const size_t hsize = FIXED_SIZE + 4 * (size_t)(degree + 1) + 4 * (size_t)count;
    if (size < hsize + CHECKSUM_SIZE)
        return tw_fail(err, TW_ERROR_INVALID, "truncated .tw file: %zu bytes, the header alone needs %zu", size,
                       hsize + CHECKSUM_SIZE);
    uint64_t expected = hsize + CHECKSUM_SIZE;
    for (int i = 0; i < count; i++) {
        section_sizes[i] = le32(data + hsize - 4 * (size_t)count + 4 * (size_t)i);
        expected += section_sizes[i];
    }
    if ((uint64_t)size < expected)
        return tw_fail(err, TW_ERROR_INVALID, "truncated .tw file: %zu bytes, the header announces %llu", size,
                       (unsigned long long)expected);
    if ((uint64_t)size > expected)
        return tw_fail(err, TW_ERROR_INVALID, "corrupted .tw file: %llu unexpected bytes after the checksum",
                       (unsigned long long)((uint64_t)size - expected));
    if (crc32_zlib(data, size - CHECKSUM_SIZE) != le32(data + size - CHECKSUM_SIZE))
        return tw_fail(err, TW_ERROR_INVALID, "corrupted .tw file: checksum mismatch");

    /* Behind a valid checksum: the remaining checks catch files written wrongly (or forged) rather than damaged. */
    const int exact = (bits_byte & BITS_EXACT) != 0, creases = (bits_byte & BITS_CREASES) != 0;
    const int bits = bits_byte & ~(BITS_EXACT | BITS_CREASES);
    const int subdivision = (flags >> 5) & 3;
    const uint32_t n = le32(data + 13);
    if (exact && (flags & FLAG_QHULL))
        return tw_fail(err, TW_ERROR_INVALID,
                       "invalid .tw header: two Delaunay backends (exact, and Qhull in flags bit 0)");
    if (subdivision > MAX_SUBDIVISION)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw header: %d subdivision levels (expected 0..%d)",
                       subdivision, MAX_SUBDIVISION);
    if (bits < 6 || bits > 16)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw header: %d position bits (expected 6..16)", bits);
    if (n > MAX_POINTS)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw header: %u points (a version-2 file holds at most %u)", n,
                       MAX_POINTS);
    const double scale = le_f64(data + 17);
    const double offset[3] = {le_f64(data + 25), le_f64(data + 33), le_f64(data + 41)};
    if (transform_problem(scale, offset, err)) return TW_ERROR_INVALID;
    const double s_step = le_f32(data + 49);
    if (step_problem("s step", s_step, MAX_S_STEP, err)) return TW_ERROR_INVALID;
    for (int l = 0; l <= degree; l++) {
        file->c_steps[l] = le_f32(data + FIXED_SIZE + 4 * l);
        if (step_problem("c step", file->c_steps[l], MAX_C_STEP, err)) return TW_ERROR_INVALID;
    }
    const int q = (degree + 1) * (degree + 1);
    int any = 0;
    for (int i = 0; i < count; i++) any |= section_sizes[i] != 0;
    if (n == 0 && any) return tw_fail(err, TW_ERROR_INVALID, "invalid .tw header: sections for zero points");
    if (n && q == 0 && section_sizes[2])
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw header: a c section without SH coefficients");
    if (!exact)
        return tw_fail(err, TW_ERROR_UNSUPPORTED,
                       "a version-2 .tw file triangulated by %s (an earlier encoder's): the Python package "
                       "tetweave_codec decodes it", flags & FLAG_QHULL ? "Qhull" : "TetGen");

    file->version = VERSION;
    file->flags = flags;
    file->sh_degree = degree;
    file->q = q;
    file->position_bits = bits;
    file->exact = exact;
    file->creases = creases;
    file->smoothing = (flags >> 3) & 3;
    file->subdivision = subdivision;
    file->n = n;
    file->scale = scale;
    memcpy(file->offset, offset, sizeof file->offset);
    file->s_step = s_step;
    file->sizes[0] = hsize;
    file->sizes[1] = section_sizes[0];
    file->sizes[2] = section_sizes[1];
    file->sizes[3] = section_sizes[2];
    file->sizes[4] = CHECKSUM_SIZE;
    return TW_OK;
}

/* tw_parse's work; defer: check the holes section's framing and record its place instead of decoding it. */
static int parse_file(const unsigned char *data, size_t size, tw_file *file, int defer, tw_error *err) {
    if (!file) return tw_fail(err, TW_ERROR_ARGUMENT, "tw_parse: no tw_file to fill");
    memset(file, 0, sizeof *file);
    if (!data && size) return tw_fail(err, TW_ERROR_ARGUMENT, "tw_parse: NULL data of %zu bytes", size);
    uint32_t sizes[4] = {0, 0, 0, 0};
    int with_holes = 0;
    int status = parse_header(data ? data : (const unsigned char *)"", size, file, sizes, &with_holes, err);
    if (status) {
        memset(file, 0, sizeof *file);
        return status;
    }
    const uint32_t n = file->n;
    if (n == 0) { /* every section is empty (checked): no points, no arrays */
        if (with_holes) { /* a holes section needs points: its empty section is truncated (holes.decode_holes) */
            status = tw_check_holes_section(data + file->sizes[0], 0, 0, err);
            if (!status) status = tw_fail(err, TW_ERROR_INVALID, "invalid .tw payload: a holes section without points");
            tw_file_free(file);
        }
        return status;
    }

    const unsigned char *sec[4];
    sec[0] = data + file->sizes[0];
    for (int i = 1; i < 4; i++) sec[i] = sec[i - 1] + sizes[i - 1];
    const size_t q = (size_t)file->q;
    int32_t *s_sym = (int32_t *)malloc((size_t)n * sizeof(int32_t));
    int32_t *residual = NULL;
    int32_t *c_sym = q ? (int32_t *)malloc((size_t)n * q * sizeof(int32_t)) : NULL;
    file->cells = (int32_t *)malloc((size_t)n * 3 * sizeof(int32_t));
    file->points = (double *)malloc((size_t)n * 3 * sizeof(double));
    file->s = (double *)malloc((size_t)n * sizeof(double));
    file->c = q ? (double *)malloc((size_t)n * q * sizeof(double)) : NULL;
    if (!s_sym || !file->cells || !file->points || !file->s || (q && (!c_sym || !file->c))) {
        status = tw_fail(err, TW_ERROR_MEMORY, "out of memory for a file of %u points", n);
        goto done;
    }
    status = tw_decode_octree(sec[0], sizes[0], file->position_bits, n, (file->flags & FLAG_OCTREE_CONTEXTS) != 0,
                              file->cells, err);
    if (status) goto done;
    if (file->flags & FLAG_S_PREDICTED) {
        residual = (int32_t *)malloc((size_t)n * sizeof(int32_t));
        if (!residual) {
            status = tw_fail(err, TW_ERROR_MEMORY, "out of memory for a file of %u points", n);
            goto done;
        }
        status = tw_decode_s_residuals(sec[1], sizes[1], n, residual, err);
        if (!status) status = tw_predict_s(file->cells, n, residual, s_sym, err);
    } else {
        status = tw_decode_s(sec[1], sizes[1], n, s_sym, err);
    }
    if (status) goto done;
    status = tw_decode_c(sec[2], sizes[2], n, file->sh_degree, c_sym, err);
    if (status) goto done;
    if (with_holes) {
        if (defer)
            status = tw_check_holes_section(sec[3], sizes[3], n, err);
        else
            status = tw_decode_holes(sec[3], sizes[3], n, &file->holes, &file->hole_count, err);
        if (status) goto done;
    }
    tw_dequantize_positions(file->cells, n, file->position_bits, file->points);
    tw_dequantize_s(s_sym, n, file->s_step, file->s);
    if (q) tw_dequantize_c(c_sym, n, file->sh_degree, file->c_steps, file->c);
done:
    free(s_sym);
    free(residual);
    free(c_sym);
    if (status) tw_file_free(file);
    return status;
}

/*
 * tw_parse -- parse and validate a `.tw` file.
 *   data, size: the file's bytes (data may be NULL when size is 0).
 *   file:       receives the header fields and malloc'ed arrays (release with tw_file_free); zeroed on failure.
 *   err:        the status and a one-line message on failure (may be NULL).
 * Returns TW_OK, TW_ERROR_INVALID (malformed, truncated or corrupted: the reference's ContainerError),
 * TW_ERROR_UNSUPPORTED (version 1, or a version-2 file not triangulated by the exact Delaunay), TW_ERROR_MEMORY,
 * TW_ERROR_ARGUMENT (file NULL, or data NULL with size > 0). Memory: O(N (4 + q)) for the N the header announces
 * (N <= 2^22), allocated only after the header and the checksum are valid, plus 14 bytes per hole face of a holes
 * section (K <= 64 N; tw_parse_deferred leaves them to the decoder, which bounds K by its surface).
 */
int tw_parse(const unsigned char *data, size_t size, tw_file *file, tw_error *err) {
    return parse_file(data, size, file, 0, err);
}

/* tw_parse_deferred -- tw_parse with the holes section's ranks left undecoded (internal.h). */
int tw_parse_deferred(const unsigned char *data, size_t size, tw_file *file, tw_error *err) {
    return parse_file(data, size, file, 1, err);
}

/* tw_file_holes_pending -- flags bit 7 (n > 0: tw_parse refuses a holes section without points) and no ranks. */
int tw_file_holes_pending(const tw_file *file) {
    return (file->flags & FLAG_HOLES) && file->n && !file->holes;
}

/*
 * tw_file_decode_holes -- the ranks of a holes section tw_parse_deferred left undecoded: data / size are the
 * file's bytes given to tw_parse_deferred (the section lies between the c section, at sizes[0..3] from the start,
 * and the checksum), max_faces the extracted surface's face count F0 (0: bounded by 64 N only). On success
 * file->holes / hole_count hold the ranks (each < F0 when max_faces is not 0). Errors: tw_decode_holes_bounded's
 * (file unchanged). TW_ERROR_ARGUMENT when size is not the parsed file's.
 */
int tw_file_decode_holes(const unsigned char *data, size_t size, tw_file *file, uint64_t max_faces, tw_error *err) {
    if (!tw_file_holes_pending(file)) return TW_OK;
    const size_t at = file->sizes[0] + file->sizes[1] + file->sizes[2] + file->sizes[3];
    if (size < at + CHECKSUM_SIZE) return tw_fail(err, TW_ERROR_ARGUMENT, "tw_file_decode_holes: not the parsed file");
    return tw_decode_holes_bounded(data + at, size - at - CHECKSUM_SIZE, file->n, max_faces, &file->holes,
                                   &file->hole_count, err);
}
