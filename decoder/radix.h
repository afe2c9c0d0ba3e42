/* radix.h -- integer helpers shared by delaunay.c, marching.c and intersect.c (header-only: each file gets its own
 * static copy). */
#ifndef TETWEAVE_RADIX_H
#define TETWEAVE_RADIX_H

#include <stdint.h>
#include <string.h>

#define TW_RADIX_BITS 11

/* Bits of v (0 for 0). */
static inline int tw_bit_length(uint64_t v) {
    int b = 0;
    while (v) {
        b++;
        v >>= 1;
    }
    return b;
}

/* Sort a[0..m) ascending by its low `bits` bits (values below 2^bits) when a is already in ascending order of its
 * low `sorted` bits (0: not at all): a stable LSD radix sort by bits sorted .. bits - 1; tmp: scratch of m items;
 * the 16 KB count table lives on the stack. */
static inline void tw_radix_sort(uint64_t *a, uint64_t *tmp, int64_t m, int sorted, int bits) {
    int64_t count[1 << TW_RADIX_BITS];
    uint64_t *src = a, *dst = tmp;
    const uint64_t mask = (1u << TW_RADIX_BITS) - 1;
    for (int shift = sorted; shift < bits; shift += TW_RADIX_BITS) {
        memset(count, 0, sizeof count);
        for (int64_t i = 0; i < m; i++) count[(src[i] >> shift) & mask]++;
        int64_t sum = 0;
        for (uint64_t d = 0; d <= mask; d++) {
            int64_t c = count[d];
            count[d] = sum;
            sum += c;
        }
        for (int64_t i = 0; i < m; i++) dst[count[(src[i] >> shift) & mask]++] = src[i];
        uint64_t *t = src;
        src = dst;
        dst = t;
    }
    if (src != a) memcpy(a, src, (size_t)m * sizeof(uint64_t));
}

#endif
