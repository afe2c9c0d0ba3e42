/*
 * core_stages.c -- time each stage of the decoder core's tw_decode on real .tw files (benchmarks/core_stages.py
 * builds and runs it; not part of the package).
 *
 * Built from the decoder/*.c of any revision, with decoder/filter.c compiled under
 *   -Dtw_self_intersecting=bench_self_intersecting -Dtw_loop_level=bench_loop_level
 *   -Dtw_half_edges=bench_half_edges -Dtw_self_intersecting_kept=bench_self_intersecting_kept
 * so that the filter's calls of those stages land in the timed wrappers below (the real functions, compiled from
 * intersect.c and loop.c without the renaming, do the work). The stages run as tw_decode_detailed runs them
 * (decode.c): parse, Delaunay, marching tets, the filter, the holes, then the export copy of decode.c.
 *
 *   core_stages [-r repeats] [-l level] [-t threads] [-c wall|cpu] [-v 1] FILE...
 *
 * Prints one line per file and run: "file run stage=ms ..." (the caller takes medians). Filter parts: edges
 * (the half-edges), loop (Loop levels), check (the first crossing check after the filter, or the
 * unfiltered surface's check), recheck (the restore rounds' checks), taubin (the rest of the filter: Taubin steps,
 * creases, the output transform, copies). total = the whole decode, export included.
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "internal.h"

static clockid_t bench_clock = CLOCK_MONOTONIC;

static double now(void) {
    struct timespec ts;
    clock_gettime(bench_clock, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* seconds spent in each wrapped stage during the current run */
static double t_edges, t_loop, t_check, t_recheck;
static int verbose; /* -v: one line per crossing check on stderr (faces, marked, flagged, ms) */

/* One crossing check's time into check or recheck (and its line with -v); st: a tw_check_state or NULL. */
static int timed_check(void *st, const double *v, size_t nv, const int32_t *f, size_t nf, const uint8_t *only,
                       const uint8_t *changed, int children, int threads, uint8_t *flags) {
    double t0 = now();
#ifdef TW_CHECK_STATE
    int status = tw_self_intersecting_kept((tw_check_state *)st, v, nv, f, nf, only, changed, children, threads,
                                           flags);
#else
    (void)st;
    (void)changed;
    int status = tw_self_intersecting(v, nv, f, nf, only, children, threads, flags);
#endif
    double dt = now() - t0;
    *(only ? &t_recheck : &t_check) += dt;
    if (verbose) {
        size_t marked = 0, flagged = 0;
        for (size_t i = 0; i < nf; i++) {
            marked += only ? only[i] != 0 : 1;
            flagged += flags[i] != 0;
        }
        fprintf(stderr, "  check: faces %zu children %d marked %zu flagged %zu status %d: %.3f ms\n", nf, children,
                marked, flagged, status, 1e3 * dt);
    }
    return status;
}

int bench_self_intersecting(const double *v, size_t nv, const int32_t *f, size_t nf, const uint8_t *only,
                            int children, int threads, uint8_t *flags) {
    return timed_check(NULL, v, nv, f, nf, only, NULL, children, threads, flags);
}

#ifdef TW_CHECK_STATE /* a core whose restore rounds keep the check's state (internal.h) */
int bench_self_intersecting_kept(tw_check_state *st, const double *v, size_t nv, const int32_t *f, size_t nf,
                                 const uint8_t *only, const uint8_t *changed, int children, int threads,
                                 uint8_t *flags) {
    return timed_check(st, v, nv, f, nf, only, changed, children, threads, flags);
}
#endif

int bench_loop_level(const double *v, const double *r, size_t nv, const int32_t *f, size_t nf, const int32_t *rows,
                     const uint8_t *crease, double *out_v, double *out_r, int32_t *out_f, int32_t *out_ends) {
    double t0 = now();
    int status = tw_loop_level(v, r, nv, f, nf, rows, crease, out_v, out_r, out_f, out_ends);
    t_loop += now() - t0;
    return status;
}

int bench_half_edges(const int32_t *f, size_t nf, size_t nv, int32_t **rows, int32_t **face_of, int32_t **twin) {
    double t0 = now();
    int status = tw_half_edges(f, nf, nv, rows, face_of, twin);
    t_edges += now() - t0;
    return status;
}

static unsigned char *read_file(const char *path, size_t *size) {
    FILE *fp = fopen(path, "rb");
    if (!fp) return NULL;
    fseek(fp, 0, SEEK_END);
    long n = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    unsigned char *data = (unsigned char *)malloc(n > 0 ? (size_t)n : 1);
    if (data && fread(data, 1, (size_t)n, fp) != (size_t)n) {
        free(data);
        data = NULL;
    }
    fclose(fp);
    *size = (size_t)n;
    return data;
}

/* One decode as decode.c's tw_decode_detailed + export, timed per stage; prints one line. Returns a status. */
static int run_once(const char *name, int run, const unsigned char *data, size_t size, int level, int threads) {
    tw_error err;
    memset(&err, 0, sizeof err);
    tw_file file;
    tw_tets tz;
    tw_surface control, closed, mesh;
    memset(&file, 0, sizeof file);
    memset(&tz, 0, sizeof tz);
    memset(&control, 0, sizeof control);
    memset(&closed, 0, sizeof closed);
    memset(&mesh, 0, sizeof mesh);
    t_edges = t_loop = t_check = t_recheck = 0;
    double t0 = now(), t_parse, t_delaunay, t_marching, t_filter, t_holes = 0, t_export;
    int status = tw_parse(data, size, &file, &err);
    t_parse = now() - t0;
    if (status) goto fail;
    int smoothing = level == TW_LEVEL_CONTROL ? 0 : file.smoothing;
    int subdivision = level == TW_LEVEL_FULL ? file.subdivision : 0;
    double t1 = now();
    status = tw_delaunay(file.cells, file.n, &tz, &err);
    t_delaunay = now() - t1;
    if (status) goto fail;
    t1 = now();
    status = tw_marching_tets(file.points, file.s, file.c, file.sh_degree, file.n, &tz, &control, &err);
    tw_tets_free(&tz);
    t_marching = now() - t1;
    if (status) goto fail;
    uint64_t restored = 0;
    int gave_up = 0;
    t1 = now();
    status = tw_filter_surface(&control, smoothing, subdivision, file.creases, file.scale, file.offset, threads,
                               &closed, &restored, &gave_up, &err);
    t_filter = now() - t1;
    if (status) goto fail;
    const tw_surface *out = &closed;
    if (file.hole_count) {
        t1 = now();
        size_t children = gave_up ? 1 : (size_t)1 << (2 * subdivision);
        status = tw_open_holes(&closed, control.f, control.nf, file.holes, file.hole_count, children, &mesh, &err);
        t_holes = now() - t1;
        if (status) goto fail;
        out = &mesh;
    }
    t1 = now();
    double *positions = (double *)malloc(out->nv * 3 * sizeof(double) + 1);
    uint32_t *indices = (uint32_t *)malloc(out->nf * 3 * sizeof(uint32_t) + 1);
    if (!positions || !indices) {
        free(positions);
        free(indices);
        status = TW_ERROR_MEMORY;
        goto fail;
    }
    if (out->nv) memcpy(positions, out->v, out->nv * 3 * sizeof(double));
    for (size_t i = 0; i < out->nf * 3; i++) indices[i] = (uint32_t)out->f[i];
    t_export = now() - t1;
    double total = now() - t0;
    /* a checksum of the output, so that two builds can be compared bit for bit */
    uint64_t hash = 1469598103934665603ull;
    const unsigned char *bytes = (const unsigned char *)positions;
    for (size_t i = 0; i < out->nv * 3 * sizeof(double); i++) hash = (hash ^ bytes[i]) * 1099511628211ull;
    bytes = (const unsigned char *)indices;
    for (size_t i = 0; i < out->nf * 3 * sizeof(uint32_t); i++) hash = (hash ^ bytes[i]) * 1099511628211ull;
    double other = t_filter - t_edges - t_loop - t_check - t_recheck;
    printf("%s %d points=%u faces=%zu restored=%llu gave_up=%d hash=%016llx parse=%.3f delaunay=%.3f "
           "marching=%.3f filter=%.3f edges=%.3f taubin=%.3f loop=%.3f check=%.3f recheck=%.3f holes=%.3f "
           "export=%.3f total=%.3f\n",
           name, run, file.n, out->nf, (unsigned long long)restored, gave_up, (unsigned long long)hash,
           1e3 * t_parse, 1e3 * t_delaunay, 1e3 * t_marching, 1e3 * t_filter, 1e3 * t_edges, 1e3 * other,
           1e3 * t_loop, 1e3 * t_check, 1e3 * t_recheck, 1e3 * t_holes, 1e3 * t_export, 1e3 * total);
    free(positions);
    free(indices);
fail:
    if (status) fprintf(stderr, "%s: %s\n", name, err.message);
    tw_file_free(&file);
    tw_tets_free(&tz);
    tw_surface_free(&control);
    tw_surface_free(&closed);
    tw_surface_free(&mesh);
    return status;
}

int main(int argc, char **argv) {
    int repeats = 5, level = TW_LEVEL_FULL, threads = 1, i = 1;
    for (; i + 1 < argc && argv[i][0] == '-'; i += 2) {
        if (!strcmp(argv[i], "-r")) repeats = atoi(argv[i + 1]);
        else if (!strcmp(argv[i], "-l")) level = atoi(argv[i + 1]);
        else if (!strcmp(argv[i], "-t")) threads = atoi(argv[i + 1]);
        else if (!strcmp(argv[i], "-v")) verbose = atoi(argv[i + 1]);
        else if (!strcmp(argv[i], "-c")) bench_clock = strcmp(argv[i + 1], "cpu") ? CLOCK_MONOTONIC
                                                                                   : CLOCK_PROCESS_CPUTIME_ID;
        else {
            fprintf(stderr, "unknown option %s\n", argv[i]);
            return 2;
        }
    }
    int status = 0;
    for (; i < argc; i++) {
        size_t size = 0;
        unsigned char *data = read_file(argv[i], &size);
        if (!data) {
            fprintf(stderr, "cannot read %s\n", argv[i]);
            return 2;
        }
        for (int r = 0; r < repeats && !status; r++) status = run_once(argv[i], r, data, size, level, threads);
        free(data);
    }
    return status ? 1 : 0;
}
