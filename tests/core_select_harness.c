/* core_select_harness.c -- the crossing check's selection helpers (decoder/intersect.c, static there) exported for
 * tests/test_core_speed.py: the whole file is included, so the tests call the code the check runs. */
#include "intersect.c"

/* first_cell of ext[0..n) (n >= 1; the reference's 2 * median, or the largest extent, or 1). */
double tw_test_first_cell(const double *ext, int64_t n) {
    double *scratch = (double *)malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    if (!scratch) return -1.0;
    double cell = first_cell(ext, scratch, n, NULL);
    free(scratch);
    return cell;
}

/* The k-th smallest of a[0..n) by kth_value (radix where it can) and by kth_smallest (Hoare) on copies; *radix: 1
 * when radix_kth answered. */
double tw_test_kth(const double *a, int64_t n, int64_t k, int hoare, int *radix) {
    double *copy = (double *)malloc(sizeof(double) * (size_t)(n > 0 ? n : 1)), out = 0;
    double *buf = (double *)malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    if (!copy || !buf) return -1.0;
    memcpy(copy, a, sizeof(double) * (size_t)n);
    *radix = radix_kth(copy, n, k, buf, &out);
    double value = hoare ? kth_smallest(copy, n, k) : kth_value(copy, n, k);
    free(copy);
    free(buf);
    return value;
}
