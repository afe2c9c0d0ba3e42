/* common.c -- what every stage of the decoder core shares: errors, status names, surfaces. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

int tw_fail(tw_error *err, int status, const char *fmt, ...) {
    /* The first failure wins: a stage that fails because a callee failed keeps the callee's message. */
    if (err && err->status == TW_OK) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err->message, sizeof err->message, fmt, ap);
        va_end(ap);
        err->status = status;
    }
    return status;
}

const char *tw_status_string(int status) {
    switch (status) {
    case TW_OK: return "ok";
    case TW_ERROR_INVALID: return "invalid file";
    case TW_ERROR_UNSUPPORTED: return "unsupported file";
    case TW_ERROR_LIMIT: return "mesh too large";
    case TW_ERROR_MEMORY: return "out of memory";
    case TW_ERROR_ARGUMENT: return "bad argument";
    case TW_ERROR_INTERNAL: return "internal error";
    default: return "unknown status";
    }
}

void tw_surface_free(tw_surface *surface) {
    if (!surface) return;
    free(surface->v);
    free(surface->f);
    memset(surface, 0, sizeof *surface);
}
