/*
 * core_parse_harness.c -- a command-line driver of tw_parse for tests/test_core_container.py (test-only code, never
 * part of the core): the test builds it with -fsanitize=address,undefined and runs it on a hostile corpus, so
 * that an out-of-bounds access, a leak or undefined behaviour anywhere in the parse aborts the process.
 *
 * Usage: core_parse_harness FILE...  -- per file one line "status n hole_count checksum" on stdout, where checksum
 * is a 64-bit FNV-1a over the parsed arrays (cells, points, s, c, holes) so the test can compare runs. Exit 0
 * unless a file cannot be read (2) or a sanitizer aborts.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../decoder/internal.h"

static uint64_t fnv(uint64_t h, const void *data, size_t size) {
    const unsigned char *p = (const unsigned char *)data;
    for (size_t i = 0; i < size; i++) h = (h ^ p[i]) * 0x100000001B3ULL;
    return h;
}

int main(int argc, char **argv) {
    for (int a = 1; a < argc; a++) {
        FILE *fp = fopen(argv[a], "rb");
        if (!fp) return 2;
        fseek(fp, 0, SEEK_END);
        long size = ftell(fp);
        fseek(fp, 0, SEEK_SET);
        /* exactly `size` bytes on the heap: a read past the file's end is a heap overflow ASan reports */
        unsigned char *data = (unsigned char *)malloc(size > 0 ? (size_t)size : 1);
        if (!data || (size > 0 && fread(data, 1, (size_t)size, fp) != (size_t)size)) return 2;
        fclose(fp);
        tw_file file;
        tw_error err = {0, ""};
        int status = tw_parse(size > 0 ? data : NULL, (size_t)size, &file, &err);
        uint64_t h = 0xCBF29CE484222325ULL;
        if (status == TW_OK) {
            size_t n = file.n, q = (size_t)file.q;
            h = fnv(h, file.cells, n * 3 * sizeof *file.cells);
            h = fnv(h, file.points, n * 3 * sizeof *file.points);
            h = fnv(h, file.s, n * sizeof *file.s);
            h = fnv(h, file.c, n * q * sizeof *file.c);
            h = fnv(h, file.holes, file.hole_count * sizeof *file.holes);
        }
        printf("%d %u %zu %016llx\n", status, status == TW_OK ? file.n : 0u, status == TW_OK ? file.hole_count : 0,
               (unsigned long long)h);
        tw_file_free(&file);
        free(data);
    }
    return 0;
}
