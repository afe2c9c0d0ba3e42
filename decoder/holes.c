/*
 * holes.c -- the decoder's last step for a file with a holes section (geometry/holes.py open_holes, face_ranks,
 * pinched_vertices are the reference): the extracted faces a holes section names by canonical rank go, with the
 * 4^L faces Loop subdivision made of each; a removal that leaves a vertex with two or more fans (not a 2-manifold
 * with boundary) is refused. Integers only: the kept vertices are copied, not computed.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

typedef struct {
    int32_t c[3]; /* the face's corners, ascending */
    int64_t index;
} RankKey;

static int compare_keys(const void *x, const void *y) {
    const RankKey *a = (const RankKey *)x, *b = (const RankKey *)y;
    for (int k = 0; k < 3; k++)
        if (a->c[k] != b->c[k]) return a->c[k] < b->c[k] ? -1 : 1;
    return (a->index > b->index) - (a->index < b->index); /* np.lexsort is stable: equal faces by index */
}

/*
 * tw_face_ranks: holes.face_ranks. The rank (nf int64) of each face of f (nf * 3) in the order of its corners
 * sorted ascending, compared lexicographically, equal keys by face index. 0, or -1 out of memory.
 */
int tw_face_ranks(const int32_t *f, size_t nf, int64_t *ranks) {
    RankKey *keys = (RankKey *)malloc(sizeof(RankKey) * (nf > 0 ? nf : 1));
    if (!keys) return -1;
    for (size_t i = 0; i < nf; i++) {
        int32_t a = f[3 * i], b = f[3 * i + 1], c = f[3 * i + 2], t;
        if (a > b) t = a, a = b, b = t;
        if (b > c) t = b, b = c, c = t;
        if (a > b) t = a, a = b, b = t;
        keys[i].c[0] = a, keys[i].c[1] = b, keys[i].c[2] = c;
        keys[i].index = (int64_t)i;
    }
    qsort(keys, nf, sizeof(RankKey), compare_keys);
    for (size_t i = 0; i < nf; i++) ranks[keys[i].index] = (int64_t)i;
    free(keys);
    return 0;
}

static int32_t find_root(int32_t *parent, int32_t x) {
    while (parent[x] != x) {
        parent[x] = parent[parent[x]]; /* path halving */
        x = parent[x];
    }
    return x;
}

static void join(int32_t *parent, int32_t x, int32_t y) {
    x = find_root(parent, x);
    y = find_root(parent, y);
    if (x != y) parent[x < y ? y : x] = x < y ? x : y;
}

typedef struct {
    int64_t key; /* min(a, b) * n + max(a, b) */
    int32_t half;
} EdgeKey;

static int compare_edges(const void *x, const void *y) {
    const EdgeKey *a = (const EdgeKey *)x, *b = (const EdgeKey *)y;
    if (a->key != b->key) return a->key < b->key ? -1 : 1;
    return (a->half > b->half) - (a->half < b->half); /* argsort(kind="stable") */
}

/*
 * Whether some vertex of faces f (nf * 3, indices in [0, n)) has its faces in more than one fan (holes.
 * pinched_vertices is not empty): corners joined across the faces' shared edges (the reference's graph: the two
 * half-edges of one undirected edge, consecutive in stable key order, join the corners of their common ends), then
 * a vertex whose corners lie in two components. 1 pinched, 0 not, -1 out of memory.
 */
static int any_pinched(const int32_t *f, size_t nf, size_t n) {
    size_t nh = 3 * nf;
    EdgeKey *keys = (EdgeKey *)malloc(sizeof(EdgeKey) * (nh > 0 ? nh : 1));
    int32_t *parent = (int32_t *)malloc(sizeof(int32_t) * (nh > 0 ? nh : 1));
    int32_t *first = (int32_t *)malloc(sizeof(int32_t) * (n > 0 ? n : 1));
    int result = 0;
    if (!keys || !parent || !first) {
        result = -1;
        goto done;
    }
    /* half-edge h = 3 face + slot runs from corner h to corner 3 face + (slot + 1) % 3 */
    for (size_t h = 0; h < nh; h++) {
        int64_t a = f[h], b = f[3 * (h / 3) + (h % 3 + 1) % 3];
        keys[h].key = (a < b ? a : b) * (int64_t)n + (a < b ? b : a);
        keys[h].half = (int32_t)h;
        parent[h] = (int32_t)h;
    }
    qsort(keys, nh, sizeof(EdgeKey), compare_edges);
    for (size_t i = 0; i + 1 < nh; i++) {
        if (keys[i].key != keys[i + 1].key) continue;
        int32_t h1 = keys[i].half, h2 = keys[i + 1].half;
        int32_t a1 = h1, b1 = 3 * (h1 / 3) + (h1 % 3 + 1) % 3, a2 = h2, b2 = 3 * (h2 / 3) + (h2 % 3 + 1) % 3;
        join(parent, a1, b2);
        join(parent, b1, a2);
    }
    for (size_t u = 0; u < n; u++) first[u] = -1;
    for (size_t h = 0; h < nh && !result; h++) {
        int32_t root = find_root(parent, (int32_t)h), u = f[h];
        if (first[u] < 0)
            first[u] = root;
        else if (first[u] != root)
            result = 1;
    }
done:
    free(keys);
    free(parent);
    free(first);
    return result;
}

/*
 * tw_open_holes: holes.open_holes (see internal.h). closed: the surface after the filter (closed->nf faces, in
 * runs of `children` per extracted face); extracted: the marching-tets faces (extracted_count * 3); ranks: the
 * holes section's `count` ranks. out receives the faces kept, in order, over the vertices they use, in order.
 */
int tw_open_holes(const tw_surface *closed, const int32_t *extracted, size_t extracted_count, const int64_t *ranks,
                  size_t count, size_t children, tw_surface *out, tw_error *err) {
    if (!closed || !out || (count && !ranks) || (extracted_count && !extracted) || children < 1)
        return tw_fail(err, TW_ERROR_ARGUMENT, "tw_open_holes: a NULL argument");
    memset(out, 0, sizeof *out);
    if (extracted_count > (size_t)INT32_MAX / 3 || extracted_count * children != closed->nf)
        return tw_fail(err, TW_ERROR_ARGUMENT, "%zu faces are not %zu per extracted face (%zu)", closed->nf, children,
                       extracted_count);
    int64_t largest = -1;
    for (size_t i = 0; i < count; i++) {
        if (ranks[i] < 0) return tw_fail(err, TW_ERROR_INVALID, "invalid .tw file: a negative hole face rank");
        if (ranks[i] > largest) largest = ranks[i];
    }
    if (largest >= (int64_t)extracted_count)
        return tw_fail(err, TW_ERROR_INVALID, "invalid .tw file: hole face rank %lld but the surface has %zu faces",
                       (long long)largest, extracted_count);
    size_t n0 = 0; /* the extracted surface's vertices: its largest index + 1 */
    for (size_t i = 0; i < 3 * extracted_count; i++) {
        if (extracted[i] < 0) return tw_fail(err, TW_ERROR_ARGUMENT, "tw_open_holes: a negative vertex index");
        if ((size_t)extracted[i] + 1 > n0) n0 = (size_t)extracted[i] + 1;
    }
    for (size_t i = 0; i < 3 * closed->nf; i++)
        if (closed->f[i] < 0 || (size_t)closed->f[i] >= closed->nv)
            return tw_fail(err, TW_ERROR_ARGUMENT, "tw_open_holes: a face index out of range");
    size_t cap = extracted_count > 0 ? extracted_count : 1;
    int64_t *rank_of = (int64_t *)malloc(sizeof(int64_t) * cap);
    uint8_t *removed = (uint8_t *)calloc(cap, 1), *gone = (uint8_t *)malloc(cap);
    int32_t *left = (int32_t *)malloc(sizeof(int32_t) * 3 * cap);
    int32_t *new_index = (int32_t *)malloc(sizeof(int32_t) * (closed->nv > 0 ? closed->nv : 1));
    int result = TW_OK;
    if (!rank_of || !removed || !gone || !left || !new_index || tw_face_ranks(extracted, extracted_count, rank_of)) {
        result = tw_fail(err, TW_ERROR_MEMORY, "out of memory opening holes");
        goto done;
    }
    for (size_t i = 0; i < count; i++) removed[ranks[i]] = 1; /* by rank */
    size_t kept_extracted = 0;
    for (size_t i = 0; i < extracted_count; i++) {
        gone[i] = removed[rank_of[i]];
        if (!gone[i]) memcpy(left + 3 * kept_extracted++, extracted + 3 * i, 3 * sizeof(int32_t));
    }
    /* a pinch of the subdivided result is a pinch of the extracted surface (holes.py): checked on the latter */
    int pinched = any_pinched(left, kept_extracted, n0);
    if (pinched < 0) {
        result = tw_fail(err, TW_ERROR_MEMORY, "out of memory opening holes");
        goto done;
    }
    if (pinched) {
        result = tw_fail(err, TW_ERROR_INVALID,
                         "invalid .tw file: its holes leave a vertex where two parts of the surface meet");
        goto done;
    }
    size_t nf = kept_extracted * children, nv = 0;
    out->f = (int32_t *)malloc(sizeof(int32_t) * 3 * (nf > 0 ? nf : 1));
    if (!out->f) {
        result = tw_fail(err, TW_ERROR_MEMORY, "out of memory opening holes");
        goto done;
    }
    for (size_t i = 0; i < closed->nv; i++) new_index[i] = -1;
    size_t o = 0;
    for (size_t i = 0; i < closed->nf; i++)
        if (!gone[i / children])
            for (int k = 0; k < 3; k++) new_index[closed->f[3 * i + k]] = 0, out->f[o++] = closed->f[3 * i + k];
    for (size_t i = 0; i < closed->nv; i++)
        if (new_index[i] >= 0) new_index[i] = (int32_t)nv++;
    out->v = (double *)malloc(sizeof(double) * 3 * (nv > 0 ? nv : 1));
    if (!out->v) {
        result = tw_fail(err, TW_ERROR_MEMORY, "out of memory opening holes");
        goto done;
    }
    for (size_t i = 0; i < closed->nv; i++)
        if (new_index[i] >= 0) memcpy(out->v + 3 * (size_t)new_index[i], closed->v + 3 * i, 3 * sizeof(double));
    for (size_t i = 0; i < o; i++) out->f[i] = new_index[out->f[i]];
    out->nv = nv;
    out->nf = nf;
done:
    if (result != TW_OK) tw_surface_free(out);
    free(rank_of);
    free(removed);
    free(gone);
    free(left);
    free(new_index);
    return result;
}
