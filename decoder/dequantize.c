/*
 * dequantize.c -- symbols to the float64 arrays a decoder triangulates (formats/README.md "Dequantization";
 * formats/quantize.py dequantize_positions, dequantize_s, dequantize_c are the reference).
 *
 * Every value is one binary64 expression evaluated as written, one rounding per operation (compile with
 * -ffp-contract=off: a fused multiply-add would change the last bit of s and c).
 */
#include "internal.h"

#define GRID_BOUND 1.2 /* quantize.GRID_BOUND: the double nearest 1.2 */

void tw_dequantize_positions(const int32_t *cells, size_t n, int bits, double *points) {
    /* ((2k + 1 - 2^b) * 1.2) / 2^b: the integer is exact in binary64, the product rounds once, the division by a
     * power of two is exact (numpy: (2 * k + (1 - n)).astype(float64) * GRID_BOUND / n). */
    const int64_t side = (int64_t)1 << bits;
    const double divisor = (double)side;
    for (size_t i = 0; i < 3 * n; i++) {
        const int64_t odd = 2 * (int64_t)cells[i] + (1 - side);
        points[i] = ((double)odd * GRID_BOUND) / divisor;
    }
}

void tw_dequantize_s(const int32_t *k, size_t n, double step, double *s) {
    /* (k + 0.5) * step: k + 0.5 is exact (|k| <= 2^20), the product rounds once. */
    for (size_t i = 0; i < n; i++) s[i] = ((double)k[i] + 0.5) * step;
}

void tw_dequantize_c(const int32_t *k, size_t n, int sh_degree, const double *band_steps, double *c) {
    /* k_j * step of band floor(sqrt(j)): coefficients l^2 .. (l + 1)^2 - 1 share band l's step. */
    const int q = (sh_degree + 1) * (sh_degree + 1);
    double steps[16];
    for (int l = 0; l <= sh_degree; l++)
        for (int j = l * l; j < (l + 1) * (l + 1); j++) steps[j] = band_steps[l];
    for (size_t i = 0; i < n; i++)
        for (int j = 0; j < q; j++) c[i * (size_t)q + (size_t)j] = (double)k[i * (size_t)q + (size_t)j] * steps[j];
}
