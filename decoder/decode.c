/*
 * decode.c -- tw_decode: the whole decoder, one stage after another (internal.h's data flow), as
 * tetweave_codec/decoder.py's decode_detailed does it:
 *
 *   tw_parse            the container: envelope, header, sections, dequantized points, s, c, holes
 *   tw_delaunay         the exact Delaunay of the cells (the cells' tets are the points' tets: the dequantization
 *                       is a uniform scale and a translation)
 *   tw_marching_tets    the control surface
 *   tw_filter_surface   the level's Taubin steps and Loop levels, the output transform, the crossing checks
 *   tw_open_holes       the holes section's faces removed (with their 4^L children, or 1 when the filter was dropped)
 *
 * Memory: the parse is (52 + 12 q) N bytes at most for N <= 2^22 points; the Delaunay O(N) tets; the holes
 * section's ranks are decoded after marching tets, K <= F0 checked before their allocation (tw_parse_deferred only
 * checks the section's framing); the filter refuses more than TW_MAX_FACES faces before it subdivides. Every stage
 * frees what it made before the next one runs where it can (formats/README.md, "Decoder limits").
 */
#include <stdlib.h>
#include <string.h>

#include "internal.h"

tw_decode_options tw_default_options(void) {
    tw_decode_options options;
    options.level = TW_LEVEL_FULL;
    options.threads = 1;
    return options;
}

void tw_mesh_free(tw_mesh *mesh) {
    if (!mesh) return;
    free(mesh->positions);
    free(mesh->indices);
    memset(mesh, 0, sizeof *mesh);
}

static void set_message(char *message, size_t message_size, const char *text) {
    if (!message || !message_size) return;
    size_t n = strlen(text);
    if (n >= message_size) n = message_size - 1;
    memcpy(message, text, n);
    message[n] = '\0';
}

/* The mesh's arrays from a surface (vertices as they are; faces widened to uint32: indices are < 2^31). */
static int export_mesh(const tw_surface *surface, tw_mesh *mesh, tw_error *err) {
    mesh->vertex_count = surface->nv;
    mesh->face_count = surface->nf;
    if (!surface->nv && !surface->nf) return TW_OK;
    mesh->positions = (double *)malloc(surface->nv * 3 * sizeof(double) + 1);
    mesh->indices = (uint32_t *)malloc(surface->nf * 3 * sizeof(uint32_t) + 1);
    if (!mesh->positions || !mesh->indices) return tw_fail(err, TW_ERROR_MEMORY, "out of memory for the mesh");
    if (surface->nv) memcpy(mesh->positions, surface->v, surface->nv * 3 * sizeof(double));
    for (size_t i = 0; i < surface->nf * 3; i++) mesh->indices[i] = (uint32_t)surface->f[i];
    return TW_OK;
}

int tw_decode_detailed(const unsigned char *data, size_t size, const tw_decode_options *options,
                       tw_decode_detail *detail, tw_error *err) {
    tw_tets tz;
    tw_surface opened;
    memset(detail, 0, sizeof *detail);
    memset(&tz, 0, sizeof tz);
    memset(&opened, 0, sizeof opened);
    tw_file *file = &detail->file;
    tw_decode_stats *stats = &detail->stats;
    int status = tw_parse_deferred(data, size, file, err);
    if (status) goto done;
    /* the level's filter (decoder.level_filter) */
    const int smoothing = options->level == TW_LEVEL_CONTROL ? 0 : file->smoothing;
    const int subdivision = options->level == TW_LEVEL_FULL ? file->subdivision : 0;
    stats->points = file->n;
    stats->level = options->level;
    stats->smoothing = smoothing;
    stats->subdivision = subdivision;
    status = tw_delaunay(file->cells, file->n, &tz, err);
    if (status) goto done;
    stats->tets = tz.nt;
    status = tw_marching_tets(file->points, file->s, file->c, file->sh_degree, file->n, &tz, &detail->control, err);
    tw_tets_free(&tz);
    if (status) goto done;
    stats->extracted_faces = detail->control.nf;
    /* The holes section's ranks, now that F0 bounds them (tw_parse checked its framing). Before the filter: the
     * reference decodes them with the container, so a stream that does not decode is reported before any filter
     * error, as there; a rank >= F0, which the reference reports after the filter, is the same error class as every
     * error the filter can give a manifold control surface (ContainerError). */
    if (tw_file_holes_pending(file)) {
        if (!detail->control.nf) {
            status = tw_fail(err, TW_ERROR_INVALID, "invalid .tw file: a holes section but the surface has 0 faces");
            goto done;
        }
        status = tw_file_decode_holes(data, size, file, detail->control.nf, err);
        if (status) goto done;
    }
    uint64_t restored = 0;
    int gave_up = 0;
    status = tw_filter_surface(&detail->control, smoothing, subdivision, file->creases, file->scale, file->offset,
                               options->threads, &detail->closed, &restored, &gave_up, err);
    if (status) goto done;
    stats->restored = restored;
    stats->gave_up = gave_up;
    if (file->hole_count) {
        const size_t children = gave_up ? 1 : (size_t)1 << (2 * subdivision);
        status = tw_open_holes(&detail->closed, detail->control.f, detail->control.nf, file->holes, file->hole_count,
                               children, &detail->mesh, err);
    }
done:
    tw_tets_free(&tz);
    tw_surface_free(&opened);
    if (status) tw_decode_detail_free(detail);
    return status;
}

void tw_decode_detail_free(tw_decode_detail *detail) {
    if (!detail) return;
    tw_file_free(&detail->file);
    tw_surface_free(&detail->control);
    tw_surface_free(&detail->closed);
    tw_surface_free(&detail->mesh);
}

const tw_surface *tw_decoded_mesh(const tw_decode_detail *detail) {
    return detail->file.hole_count ? &detail->mesh : &detail->closed;
}

static int decode_file(const unsigned char *data, size_t size, const tw_decode_options *options, tw_mesh *mesh,
                       tw_error *err) {
    tw_decode_detail detail;
    int status = tw_decode_detailed(data, size, options, &detail, err);
    if (status) return status;
    mesh->stats = detail.stats;
    /* the control surface and the closed surface are not needed any more: free them before the copy */
    tw_surface_free(&detail.control);
    status = export_mesh(tw_decoded_mesh(&detail), mesh, err);
    tw_decode_detail_free(&detail);
    return status;
}

int tw_decode(const unsigned char *data, size_t size, const tw_decode_options *options, tw_mesh *mesh,
              char *message, size_t message_size) {
    tw_error err;
    memset(&err, 0, sizeof err);
    set_message(message, message_size, "");
    if (!mesh) {
        set_message(message, message_size, "tw_decode: mesh is NULL");
        return TW_ERROR_ARGUMENT;
    }
    memset(mesh, 0, sizeof *mesh);
    tw_decode_options opt = options ? *options : tw_default_options();
    int status = TW_OK;
    if (opt.level < TW_LEVEL_CONTROL || opt.level > TW_LEVEL_FULL)
        status = tw_fail(&err, TW_ERROR_ARGUMENT, "unknown decode level %d: use 0 (control), 1 (smoothed), 2 (full)",
                         opt.level);
    else if (opt.threads < 1)
        status = tw_fail(&err, TW_ERROR_ARGUMENT, "threads must be at least 1, got %d", opt.threads);
    else if (!data && size)
        status = tw_fail(&err, TW_ERROR_ARGUMENT, "tw_decode: data is NULL");
    else
        status = decode_file(data, size, &opt, mesh, &err);
    if (status) {
        tw_mesh_free(mesh);
        if (err.status == TW_OK) tw_fail(&err, status, "%s", tw_status_string(status));
        set_message(message, message_size, err.message);
    }
    return status;
}
