/* Integer helpers shared by the geometry extensions (_mt_native.c, _intersect_native.c): header-only, each
 * extension gets its own static copy. */
#ifndef TETWEAVE_GEOMETRY_NATIVE_SORT_H
#define TETWEAVE_GEOMETRY_NATIVE_SORT_H

#include <stdint.h>
#include <string.h>

#define RADIX_BITS 11

static inline int bit_length(uint64_t v) {
    int b = 0;
    while (v) {
        b++;
        v >>= 1;
    }
    return b;
}

/* Sort a[0..m) ascending by its low `bits` bits (values below 2**bits); tmp: scratch of m items. */
static inline void radix_sort(uint64_t *a, uint64_t *tmp, int64_t m, int bits) {
    int64_t count[1 << RADIX_BITS];
    uint64_t *src = a, *dst = tmp;
    const uint64_t mask = (1u << RADIX_BITS) - 1;
    for (int shift = 0; shift < bits; shift += RADIX_BITS) {
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
