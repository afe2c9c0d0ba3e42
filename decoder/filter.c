/*
 * filter.c -- the decoder core's filter of the extracted surface (geometry/surface_filter.py filter_surface is the
 * reference, with geometry/smoothing.py and geometry/subdivision.py): Taubin smoothing (crease-preserving with the
 * file's crease bit), Loop levels (loop.c), the output transform v * scale + offset, and the restore rounds that put
 * the vertices of crossing faces back to the unfiltered surface (intersect.c checks). Every binary64 operation is
 * the reference's, in its order (compile with -ffp-contract=off, no -ffast-math): the output is its bits.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

/*
 * tw_taubin: smoothing.taubin's numpy steps on v (nv * 3 doubles, in place) over the directed rows (ne of them,
 * 2 int32 each, in [0, nv) -- trusted): for f = lam then f = mu, per step, every vertex with neighbours at once:
 * v_i <- v_i + f * (sum_j v_j / deg_i - v_i), the sum from 0.0 in row order (np.bincount's), deg_i its rows.
 * Returns 0, or -1 out of memory (v unchanged).
 */
int tw_taubin(double *v, size_t nv, const int32_t *rows, size_t ne, int steps, double lam, double mu) {
    size_t cap = nv > 0 ? nv : 1;
    double *sum = (double *)malloc(sizeof(double) * 3 * cap);
    double *deg = (double *)calloc(cap, sizeof(double));
    if (!sum || !deg) {
        free(sum);
        free(deg);
        return -1;
    }
    for (size_t i = 0; i < ne; i++) deg[rows[2 * i]] += 1.0;
    for (int s = 0; s < steps; s++)
        for (int half = 0; half < 2; half++) {
            double fac = half ? mu : lam;
            memset(sum, 0, sizeof(double) * 3 * cap);
            for (size_t i = 0; i < ne; i++) {
                const double *p = v + 3 * (size_t)rows[2 * i + 1];
                double *t = sum + 3 * (size_t)rows[2 * i];
                t[0] += p[0];
                t[1] += p[1];
                t[2] += p[2];
            }
            for (size_t i = 0; i < nv; i++) {
                if (!(deg[i] > 0)) continue;
                for (int k = 0; k < 3; k++) {
                    double x = v[3 * i + k];
                    v[3 * i + k] = x + fac * (sum[3 * i + k] / deg[i] - x);
                }
            }
        }
    free(sum);
    free(deg);
    return 0;
}

static inline double dot3(const double *u, const double *w) { return (u[0] * w[0] + u[1] * w[1]) + u[2] * w[2]; }

/*
 * tw_crease_rows: smoothing.crease_edges of a closed manifold. Per row i of tw_half_edges (3 nf rows, face_of and
 * twin from it): with n = (v1 - v0) x (v2 - v0) of the row's face (n1) and of its twin's (n2), sharp[i] =
 * dot(n1, n2) < cosine * sqrt(dot(n1, n1)) * sqrt(dot(n2, n2)) (left to right, as the reference). Returns 0, or
 * -1 out of memory.
 */
int tw_crease_rows(const double *v, const int32_t *f, size_t nf, const int32_t *face_of, const int32_t *twin,
                   double cosine, uint8_t *sharp) {
    double *normal = (double *)malloc(sizeof(double) * 3 * (nf > 0 ? nf : 1));
    if (!normal) return -1;
    for (size_t i = 0; i < nf; i++) {
        const double *p0 = v + 3 * (size_t)f[3 * i], *p1 = v + 3 * (size_t)f[3 * i + 1];
        const double *p2 = v + 3 * (size_t)f[3 * i + 2];
        double u[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
        double w[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        double *n = normal + 3 * i;
        n[0] = u[1] * w[2] - u[2] * w[1];
        n[1] = u[2] * w[0] - u[0] * w[2];
        n[2] = u[0] * w[1] - u[1] * w[0];
    }
    for (size_t i = 0; i < 3 * nf; i++) {
        const double *n1 = normal + 3 * (size_t)face_of[i], *n2 = normal + 3 * (size_t)face_of[twin[i]];
        double bound = cosine * sqrt(dot3(n1, n1)) * sqrt(dot3(n2, n2));
        sharp[i] = dot3(n1, n2) < bound;
    }
    free(normal);
    return 0;
}

/* v * scale + offset per coordinate (two roundings: surface_filter._transformed) into out; a copy when offset is
 * NULL (the reference returns v itself). */
static void transformed(const double *v, size_t nv, double scale, const double *offset, double *out) {
    if (!offset) {
        if (out != v) memcpy(out, v, sizeof(double) * 3 * nv);
        return;
    }
    for (size_t i = 0; i < nv; i++)
        for (int k = 0; k < 3; k++) out[3 * i + k] = v[3 * i + k] * scale + offset[k];
}

/* n with thousands separators (Python's f"{n:,}") into buf. */
static const char *commas(uint64_t n, char *buf, size_t size) {
    char digits[32];
    int len = snprintf(digits, sizeof digits, "%llu", (unsigned long long)n);
    size_t o = 0;
    for (int i = 0; i < len && o + 1 < size; i++) {
        if (i > 0 && (len - i) % 3 == 0 && o + 2 < size) buf[o++] = ',';
        buf[o++] = digits[i];
    }
    buf[o] = 0;
    return buf;
}

static int memory(tw_error *err) { return tw_fail(err, TW_ERROR_MEMORY, "out of memory in the decoder's filter"); }

/* A status of tw_self_intersecting as tw_filter_surface reports it (-1 memory, -2 an index out of range). */
static int check_failed(int status, tw_error *err) {
    if (status == -1) return memory(err);
    return tw_fail(err, TW_ERROR_INTERNAL, "the crossing check was given a face index out of range");
}

/*
 * surface_filter._checked_control: the unfiltered surface (v0, f0) in the output frame, into a new surface `out`
 * (faces copied), checked: TW_ERROR_INVALID when two of its faces cross or touch or the check cannot bound its
 * work (the reference's ContainerErrors).
 */
static int checked_control(const tw_surface *c, double scale, const double *offset, int threads, tw_surface *out,
                           tw_error *err) {
    memset(out, 0, sizeof *out);
    out->v = (double *)malloc(sizeof(double) * 3 * (c->nv > 0 ? c->nv : 1));
    out->f = (int32_t *)malloc(sizeof(int32_t) * 3 * (c->nf > 0 ? c->nf : 1));
    if (!out->v || !out->f) {
        tw_surface_free(out);
        return memory(err);
    }
    out->nv = c->nv;
    out->nf = c->nf;
    transformed(c->v, c->nv, scale, offset, out->v);
    if (c->nf) memcpy(out->f, c->f, sizeof(int32_t) * 3 * c->nf);
    if (c->nf < 2) return TW_OK;
    uint8_t *bad = (uint8_t *)malloc(c->nf);
    if (!bad) {
        tw_surface_free(out);
        return memory(err);
    }
    int status = tw_self_intersecting(out->v, out->nv, out->f, out->nf, NULL, 1, threads, bad), result = TW_OK;
    if (status == 1)
        result = tw_fail(err, TW_ERROR_INVALID,
                         "invalid .tw file: its surface cannot be checked for self-intersections within the "
                         "decoder's work bound");
    else if (status != 0)
        result = check_failed(status, err);
    else {
        uint64_t count = 0;
        for (size_t i = 0; i < c->nf; i++) count += bad[i] != 0;
        char buf[40];
        if (count)
            result = tw_fail(err, TW_ERROR_INVALID,
                             "invalid .tw file: %s faces of its surface cross or touch other faces",
                             commas(count, buf, sizeof buf));
    }
    free(bad);
    if (result != TW_OK) tw_surface_free(out);
    return result;
}

/*
 * surface_filter.restore_crossings on v (nv * 3, in place) against reference (nv * 3) over faces f (nf * 3):
 * check, put the not yet restored vertices of crossing faces back to the reference, check again the pairs with a
 * face that changed or crossed, at most TW_MAX_CHECKS checks. *gave_up = 1 when the last check still finds
 * crossing faces, when crossing faces are all at their reference already, or when the check cannot bound its
 * work (the caller then drops the filter); else *restored = the vertices put back. Returns TW_OK or an error.
 */
static int restore_crossings(double *v, const double *reference, size_t nv, const int32_t *f, size_t nf,
                             int children, int threads, uint64_t *restored, int *gave_up, tw_error *err) {
    uint8_t *bad = (uint8_t *)malloc(nf > 0 ? nf : 1), *interest = (uint8_t *)malloc(nf > 0 ? nf : 1);
    uint8_t *done = (uint8_t *)calloc(nv > 0 ? nv : 1, 1), *back = (uint8_t *)malloc(nv > 0 ? nv : 1);
    uint8_t *changed = (uint8_t *)malloc(nf > 0 ? nf : 1); /* faces with a vertex put back since the last check */
    /* the checks after the first mark few faces: their boxes, grid and count are kept from check to check */
    tw_check_state *state = tw_check_state_new();
    int result = TW_OK, use_interest = 0; /* the first check tests every pair */
    *gave_up = 1;
    *restored = 0;
    if (!bad || !interest || !done || !back || !changed || !state) {
        result = memory(err);
        goto out;
    }
    for (int check = 0; check < TW_MAX_CHECKS; check++) {
        /* later checks test only pairs with a face that just changed or crossed at the last check: a pair of two
         * other faces was tested at these same positions and did not cross (the reference's argument) */
        int status = tw_self_intersecting_kept(state, v, nv, f, nf, use_interest ? interest : NULL,
                                               use_interest ? changed : NULL, children, threads, bad);
        if (status == 1) break; /* the check cannot bound its work: no filter */
        if (status != 0) {
            result = check_failed(status, err);
            goto out;
        }
        int any = 0;
        for (size_t i = 0; i < nf && !any; i++) any = bad[i] != 0;
        if (!any) {
            uint64_t count = 0;
            for (size_t i = 0; i < nv; i++) count += done[i];
            *restored = count;
            *gave_up = 0;
            goto out;
        }
        if (check == TW_MAX_CHECKS - 1) break;
        memset(back, 0, nv);
        for (size_t i = 0; i < nf; i++)
            if (bad[i]) back[f[3 * i]] = back[f[3 * i + 1]] = back[f[3 * i + 2]] = 1;
        int moved = 0;
        for (size_t i = 0; i < nv; i++) {
            back[i] = back[i] && !done[i];
            if (!back[i]) continue;
            moved = 1;
            memcpy(v + 3 * i, reference + 3 * i, 3 * sizeof(double));
            done[i] = 1;
        }
        if (!moved) break; /* the crossing faces are at their reference already: more checks find them again */
        for (size_t i = 0; i < nf; i++) {
            changed[i] = (uint8_t)(back[f[3 * i]] || back[f[3 * i + 1]] || back[f[3 * i + 2]]);
            interest[i] = (uint8_t)(bad[i] || changed[i]);
        }
        use_interest = 1;
    }
out:
    tw_check_state_free(state);
    free(changed);
    free(bad);
    free(interest);
    free(done);
    free(back);
    return result;
}

/*
 * tw_filter_surface: surface_filter.filter_surface (see internal.h). control: the marching-tets surface (a closed,
 * consistently oriented 2-manifold; TW_ERROR_INTERNAL otherwise, where the reference would run its numpy path),
 * in the normalized frame; smoothing: Taubin steps (<= 0: none); subdivision: Loop levels (<= 0: none); creases:
 * the crease-preserving variant of both; scale, offset: the output transform (offset NULL: none); threads: the
 * crossing checks' (>= 1). out receives a new surface in the output frame (zeroed on failure); restored: the
 * vertices put back (nv of the control surface when the filter was dropped); gave_up: the filter was dropped.
 */
int tw_filter_surface(const tw_surface *control, int smoothing, int subdivision, int creases, double scale,
                      const double offset[3], int threads, tw_surface *out, uint64_t *restored, int *gave_up,
                      tw_error *err) {
    if (!control || !out || !restored || !gave_up || (control->nv && !control->v) || (control->nf && !control->f))
        return tw_fail(err, TW_ERROR_ARGUMENT, "tw_filter_surface: a NULL argument");
    memset(out, 0, sizeof *out);
    *restored = 0;
    *gave_up = 0;
    if (threads < 1) threads = 1;
    size_t nv0 = control->nv, nf0 = control->nf;
    if (nf0 > TW_MAX_FACES || nv0 > (size_t)INT32_MAX / 3) /* also keeps every size below in range on wasm32 */
        return tw_fail(err, TW_ERROR_LIMIT, "the surface to filter has more than %u faces or 2^31 / 3 vertices",
                       (unsigned)TW_MAX_FACES);
    if (subdivision > 0) { /* the refusal of a subdivided surface over the cap comes first, as in the reference */
        uint64_t faces = nf0;
        for (int l = 0; l < subdivision && faces <= TW_MAX_FACES; l++) faces *= 4;
        if (faces > TW_MAX_FACES) {
            char a[40], b[40];
            return tw_fail(err, TW_ERROR_LIMIT,
                           "invalid .tw file: %d subdivision levels of %s faces exceed the decoder's %s", subdivision,
                           commas(nf0, a, sizeof a), commas(TW_MAX_FACES, b, sizeof b));
        }
    }
    if ((smoothing <= 0 && subdivision <= 0) || nf0 == 0)
        return checked_control(control, scale, offset, threads, out, err);
    int result = TW_OK;
    int32_t *rows = NULL, *face_of = NULL, *twin = NULL, *smooth_rows = NULL, *level_rows = NULL, *ends = NULL;
    uint8_t *sharp = NULL, *crease = NULL, *next_crease = NULL;
    double *v = NULL, *ref = NULL, *nv_buf = NULL, *nr_buf = NULL;
    int32_t *f = NULL, *nf_buf = NULL;
    size_t nh = 3 * nf0, smooth_count = nh;
    int status = tw_half_edges(control->f, nf0, nv0, &rows, creases ? &face_of : NULL, creases ? &twin : NULL);
    if (status != 0) {
        result = status < 0 ? memory(err)
                            : tw_fail(err, TW_ERROR_INTERNAL,
                                      "the surface to filter is not a closed, consistently oriented 2-manifold");
        goto fail;
    }
    smooth_rows = rows;
    if (creases) {
        /* the creases of the surface as extracted; the Taubin steps average along them (per directed row), the
         * first Loop level takes each edge's from its row (a, b) with a < b */
        sharp = (uint8_t *)malloc(nh);
        crease = (uint8_t *)malloc(nh / 2 + 1);
        int64_t *count = (int64_t *)calloc(nv0 > 0 ? nv0 : 1, sizeof(int64_t));
        smooth_rows = (int32_t *)malloc(sizeof(int32_t) * 2 * nh);
        if (!sharp || !crease || !count || !smooth_rows || tw_crease_rows(control->v, control->f, nf0, face_of, twin,
                                                                         TW_CREASE_COS, sharp) != 0) {
            free(count);
            result = memory(err);
            goto fail;
        }
        size_t e = 0;
        for (size_t i = 0; i < nh; i++) {
            if (sharp[i]) count[rows[2 * i]]++;
            if (rows[2 * i] < rows[2 * i + 1]) crease[e++] = sharp[i];
        }
        smooth_count = 0;
        for (size_t i = 0; i < nh; i++) {
            int64_t c = count[rows[2 * i]];
            if (c == 0 ? !sharp[i] : (c == 2 && sharp[i])) {
                smooth_rows[2 * smooth_count] = rows[2 * i];
                smooth_rows[2 * smooth_count + 1] = rows[2 * i + 1];
                smooth_count++;
            }
        }
        free(count);
    }
    size_t nv = nv0, nf = nf0, parent_nv = 0, parent_ne = 0;
    v = (double *)malloc(sizeof(double) * 3 * nv0);
    ref = (double *)malloc(sizeof(double) * 3 * nv0);
    f = (int32_t *)malloc(sizeof(int32_t) * 3 * nf0);
    if (!v || !ref || !f) {
        result = memory(err);
        goto fail;
    }
    memcpy(v, control->v, sizeof(double) * 3 * nv0);
    memcpy(ref, control->v, sizeof(double) * 3 * nv0);
    memcpy(f, control->f, sizeof(int32_t) * 3 * nf0);
    if (smoothing > 0 && tw_taubin(v, nv, smooth_rows, smooth_count, smoothing, TW_TAUBIN_LAMBDA, TW_TAUBIN_MU) != 0) {
        result = memory(err);
        goto fail;
    }
    for (int level = 0; level < subdivision; level++) {
        const int32_t *lr = rows;
        if (level > 0) {
            free(level_rows);
            level_rows = NULL;
            status = tw_half_edges(f, nf, nv, &level_rows, NULL, NULL);
            if (status != 0) {
                result = status < 0 ? memory(err) : tw_fail(err, TW_ERROR_INTERNAL, "a Loop level is not a manifold");
                goto fail;
            }
            lr = level_rows;
            if (crease) { /* this level's creases: the halves of the last level's */
                next_crease = (uint8_t *)malloc(3 * nf / 2 + 1);
                if (!next_crease) {
                    result = memory(err);
                    goto fail;
                }
                tw_child_creases(lr, 3 * nf, parent_nv, ends, parent_ne, crease, next_crease);
                free(crease);
                crease = next_crease;
                next_crease = NULL;
            }
        }
        size_t ne = 3 * nf / 2, size = nv + ne;
        nv_buf = (double *)malloc(sizeof(double) * 3 * size);
        nr_buf = (double *)malloc(sizeof(double) * 3 * size);
        nf_buf = (int32_t *)malloc(sizeof(int32_t) * 12 * nf);
        int32_t *new_ends = crease ? (int32_t *)malloc(sizeof(int32_t) * 2 * (ne > 0 ? ne : 1)) : NULL;
        if (!nv_buf || !nr_buf || !nf_buf || (crease && !new_ends)) {
            free(new_ends);
            result = memory(err);
            goto fail;
        }
        status = tw_loop_level(v, ref, nv, f, nf, lr, crease, nv_buf, nr_buf, nf_buf, new_ends);
        if (status != 0) {
            free(new_ends);
            result = status < 0 ? memory(err) : tw_fail(err, TW_ERROR_INTERNAL, "a Loop level is not a manifold");
            goto fail;
        }
        free(ends);
        ends = new_ends;
        free(v);
        free(ref);
        free(f);
        v = nv_buf, ref = nr_buf, f = nf_buf;
        nv_buf = nr_buf = NULL;
        nf_buf = NULL;
        parent_nv = nv;
        parent_ne = ne;
        nv = size;
        nf *= 4;
    }
    /* the output frame for both, then the restore rounds on the coordinates returned */
    transformed(v, nv, scale, offset, v);
    transformed(ref, nv, scale, offset, ref);
    result = restore_crossings(v, ref, nv, f, nf, subdivision > 0 ? 4 : 1, threads, restored, gave_up, err);
    if (result != TW_OK) goto fail;
    if (*gave_up) {
        result = checked_control(control, scale, offset, threads, out, err);
        if (result != TW_OK) goto fail;
        *restored = nv0;
        *gave_up = 1;
    } else {
        out->v = v, out->f = f, out->nv = nv, out->nf = nf;
        v = NULL;
        f = NULL;
    }
    goto done;
fail:
    memset(out, 0, sizeof *out);
    *restored = 0;
    *gave_up = 0;
done:
    if (smooth_rows != rows) free(smooth_rows);
    free(rows);
    free(face_of);
    free(twin);
    free(level_rows);
    free(ends);
    free(sharp);
    free(crease);
    free(next_crease);
    free(v);
    free(ref);
    free(f);
    free(nv_buf);
    free(nr_buf);
    free(nf_buf);
    return result;
}
