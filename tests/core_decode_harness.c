/*
 * core_decode_harness.c -- a command-line driver of the whole tw_decode for tests/test_core_fuzz.py and
 * benchmarks/fuzz.py (test-only code, never part of the core). Built with -fsanitize=address,undefined
 * -fno-sanitize-recover=all it turns an out-of-bounds access, a leak or undefined behaviour anywhere in the decode
 * into a failed file; built plainly with --limit-mb it shows the decode stays within a memory bound.
 *
 * Usage: core_decode_harness [--level L] [--threads T] [--limit-mb M] [--out DIR] FILE...
 *   Each file is decoded in a child process of its own (fork), so that a crash, a sanitizer abort or a runaway
 *   allocation is that file's outcome and the peak RSS measured (wait4) is that decode's alone.
 *   --level: 0 control, 1 smoothed, 2 full (default); --threads: tw_decode_options.threads (default 1);
 *   --limit-mb: RLIMIT_AS of each child in MiB (0 = none, the default; leave it 0 under ASan, whose shadow memory
 *   reserves terabytes of address space); --out: the decoded arrays of file i are written to DIR/i.v (float64
 *   positions) and DIR/i.f (uint32 indices) when the decode succeeds.
 * Output: per file one line "i status vertex_count face_count peak_rss_kib message" (status: tw_status, or
 * 100 + signal when the child was killed by a signal, 99 when it exited otherwise); on stderr "== i FILE" before
 * each file's decode, so that a sanitizer report names its file. Exit 0 when every child
 * ended normally, 1 otherwise (a crash or a sanitizer report), 2 on a usage or I/O error.
 */
#define _DEFAULT_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/time.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include "../decoder/tetweave_decoder.h"

/* Reads a whole file into exactly `size` heap bytes (a read past the end is then a heap overflow ASan reports). */
static unsigned char *read_file(const char *path, size_t *size) {
    FILE *fp = fopen(path, "rb");
    if (!fp) return NULL;
    fseek(fp, 0, SEEK_END);
    long n = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    unsigned char *data = n >= 0 ? (unsigned char *)malloc(n > 0 ? (size_t)n : 1) : NULL;
    if (data && n > 0 && fread(data, 1, (size_t)n, fp) != (size_t)n) {
        free(data);
        data = NULL;
    }
    fclose(fp);
    *size = n > 0 ? (size_t)n : 0;
    return data;
}

static int write_array(const char *dir, int index, const char *ext, const void *data, size_t bytes) {
    char path[4096];
    snprintf(path, sizeof path, "%s/%d.%s", dir, index, ext);
    FILE *fp = fopen(path, "wb");
    if (!fp) return 1;
    int bad = bytes && fwrite(data, 1, bytes, fp) != bytes;
    return fclose(fp) || bad;
}

/* The child: decode one file, report on `report` (one line), exit 0 (or 2 on an I/O error). */
static int decode_one(int index, const char *path, const tw_decode_options *opt, long limit_mb, const char *out,
                      FILE *report) {
    if (limit_mb > 0) {
        struct rlimit lim;
        lim.rlim_cur = lim.rlim_max = (rlim_t)limit_mb << 20;
        if (setrlimit(RLIMIT_AS, &lim)) return 2;
    }
    size_t size = 0;
    unsigned char *data = read_file(path, &size);
    if (!data) return 2;
    tw_mesh mesh;
    char message[256];
    int status = tw_decode(size ? data : NULL, size, opt, &mesh, message, sizeof message);
    free(data);
    int io = 0;
    if (status == TW_OK && out) {
        io |= write_array(out, index, "v", mesh.positions, mesh.vertex_count * 3 * sizeof(double));
        io |= write_array(out, index, "f", mesh.indices, mesh.face_count * 3 * sizeof(uint32_t));
    }
    fprintf(report, "%d %zu %zu %s\n", status, mesh.vertex_count, mesh.face_count, message);
    tw_mesh_free(&mesh);
    return io ? 2 : 0;
}

int main(int argc, char **argv) {
    tw_decode_options opt = tw_default_options();
    long limit_mb = 0;
    const char *out = NULL;
    int a = 1;
    for (; a + 1 < argc && strncmp(argv[a], "--", 2) == 0; a += 2) {
        if (!strcmp(argv[a], "--level")) opt.level = atoi(argv[a + 1]);
        else if (!strcmp(argv[a], "--threads")) opt.threads = atoi(argv[a + 1]);
        else if (!strcmp(argv[a], "--limit-mb")) limit_mb = atol(argv[a + 1]);
        else if (!strcmp(argv[a], "--out")) out = argv[a + 1];
        else {
            fprintf(stderr, "unknown option %s\n", argv[a]);
            return 2;
        }
    }
    int failed = 0;
    for (int index = 0; a < argc; a++, index++) {
        int pipefd[2];
        if (pipe(pipefd)) return 2;
        fflush(stdout);
        fprintf(stderr, "== %d %s\n", index, argv[a]); /* what follows on stderr (a sanitizer report) is this file's */
        fflush(stderr);
        pid_t pid = fork();
        if (pid < 0) return 2;
        if (pid == 0) {
            close(pipefd[0]);
            FILE *report = fdopen(pipefd[1], "w");
            int rc = report ? decode_one(index, argv[a], &opt, limit_mb, out, report) : 2;
            if (report) fclose(report);
            exit(rc);
        }
        close(pipefd[1]);
        char line[512] = "";
        FILE *in = fdopen(pipefd[0], "r");
        if (!in || !fgets(line, sizeof line, in)) line[0] = '\0';
        if (in) fclose(in);
        int wstatus = 0;
        struct rusage usage;
        memset(&usage, 0, sizeof usage);
        if (wait4(pid, &wstatus, 0, &usage) < 0) return 2;
        line[strcspn(line, "\n")] = '\0';
        if (WIFEXITED(wstatus) && WEXITSTATUS(wstatus) == 0 && line[0]) {
            char *p = line;
            long status = strtol(p, &p, 10);
            unsigned long long nv = strtoull(p, &p, 10), nf = strtoull(p, &p, 10);
            printf("%d %ld %llu %llu %ld %s\n", index, status, nv, nf, usage.ru_maxrss, *p ? p + 1 : "");
        } else {
            int code = WIFSIGNALED(wstatus) ? 100 + WTERMSIG(wstatus) : 99;
            printf("%d %d 0 0 %ld %s\n", index, code, usage.ru_maxrss, "the decoding process did not end normally");
            failed = 1;
        }
    }
    return failed;
}
