/*
 * align.cl -- translation alignment of a hand-held bracket by median threshold bitmaps
 * (Ward 2003, "Fast, robust image registration for compositing high dynamic range
 * photographs from hand-held exposures"). NumPy twin: hdrcl.align (grey_image,
 * downsample, threshold_bitmaps, shift_costs). Everything is integer, so the kernels
 * and the twin agree exactly.
 *
 *   grey        Z -> grey = (54 R + 183 G + 19 B) >> 8 (or the single channel), ushort
 *   downsample  next pyramid level: 2x2 box, (a + b + c + d + 2) >> 2; an odd last
 *               row or column is dropped (dst is floor(h/2) x floor(w/2))
 *   threshold   threshold bitmap tb = grey > t, exclusion bitmap eb = |grey - t| > tol,
 *               both bit-packed. t is the level's median (Ward), or another percentile
 *               shared by the pair when a median is clipped (chosen on the host)
 *   shift_cost  for the 9 shifts (cy + j - 1, cx + i - 1), j, i in 0..2, of frame 2
 *               against frame 1: counts[3 j + i] = number of pixels (y, x) of frame 1 with
 *               (tb1(y, x) ^ tb2(y + dy, x + dx)) & eb1(y, x) & eb2(y + dy, x + dx).
 *               Pixels of frame 2 outside the image are excluded (count nothing).
 *
 * Bitmap layout: row-major rows of `words` = ceil(w / 32) uint words; pixel (y, x) is
 * bit (x & 31) of word y * words + (x >> 5). Padding bits past the row's end are 0 in
 * both bitmaps, so they never count.
 *
 * Build options
 *   -DPIXEL_T=uchar|ushort  integer type of the frame's codes (grey; default uchar)
 *   -DNCH=n                 channels per pixel, 1 or >= 3 (grey; the first three are
 *                           R, G, B; default 3)
 *   -DWG=n                  work-group size of shift_cost, a power of two (default 64)
 *
 * Arguments (units, layout)
 *   frame     PIXEL_T [npix][NCH]  codes of a strip of rows, channels interleaved
 *   grey      ushort [h][w]        grey level of each pixel, in code units of the frame
 *   offset                         pixel index in `grey` of the strip's first pixel
 *   src, dst  ushort [sh][sw], [dh][dw]   pyramid levels k and k + 1
 *   tb, eb    uint [h][words]      threshold and exclusion bitmaps (layout above)
 *   t, tol                         threshold of the level (an order statistic of its
 *                                  grey levels) and the noise tolerance, code units
 *   counts    uint [9]             mismatching pixels per candidate shift; accumulated
 *                                  with atomic_add, so zero it before the call
 *   cy, cx                         centre of the 9 candidates, pixels of this level
 */
#ifndef PIXEL_T
#define PIXEL_T uchar
#endif
#ifndef NCH
#define NCH 3
#endif
#ifndef WG
#define WG 64
#endif

__kernel void grey(__global const PIXEL_T *frame,
                   __global ushort *grey,
                   const int npix,
                   const int offset)
{
    const int i = get_global_id(0);
    if (i >= npix)
        return;
    const size_t v = (size_t)i * NCH;
#if NCH == 1
    const uint g = frame[v];
#else
    /* 256 * 65535 fits a uint: no overflow for 16-bit codes */
    const uint g = (54u * frame[v] + 183u * frame[v + 1] + 19u * frame[v + 2]) >> 8;
#endif
    grey[(size_t)offset + i] = (ushort)g;
}

__kernel void downsample(__global const ushort *src,
                         __global ushort *dst,
                         const int sw,
                         const int dh,
                         const int dw)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (x >= dw || y >= dh)
        return;
    const size_t s = (size_t)(2 * y) * sw + 2 * x;
    const uint sum = (uint)src[s] + src[s + 1] + src[s + sw] + src[s + sw + 1];
    dst[(size_t)y * dw + x] = (ushort)((sum + 2u) >> 2);
}

/* One work item per bitmap word: 32 pixels of one row. */
__kernel void threshold(__global const ushort *grey,
                        __global uint *tb,
                        __global uint *eb,
                        const int h,
                        const int w,
                        const int words,
                        const int t,
                        const int tol)
{
    const int k = get_global_id(0);
    const int y = get_global_id(1);
    if (k >= words || y >= h)
        return;
    const int x0 = k * 32;
    const int n = min(32, w - x0);
    __global const ushort *row = grey + (size_t)y * w + x0;
    uint tw = 0u, ew = 0u;
    for (int b = 0; b < n; ++b) {
        const int g = row[b];
        tw |= (uint)(g > t) << b;
        ew |= (uint)(abs(g - t) > tol) << b;
    }
    const size_t o = (size_t)y * words + k;
    tb[o] = tw;
    eb[o] = ew;
}

/* Bits s .. s+31 of bitmap row `row` as one word (bit 0 = pixel s); bits outside the
 * row read 0. s may be negative. */
inline uint fetch(__global const uint *bm, const int row, const int words, const int s)
{
    const int w0 = s >> 5; /* floor(s / 32), also for negative s */
    const int off = s & 31;
    __global const uint *r = bm + (size_t)row * words;
    const uint lo = (w0 >= 0 && w0 < words) ? r[w0] : 0u;
    if (off == 0) /* OpenCL masks shift counts: x << 32 would be x, not 0 */
        return lo;
    const uint hi = (w0 + 1 >= 0 && w0 + 1 < words) ? r[w0 + 1] : 0u;
    return (lo >> off) | (hi << (32 - off));
}

/* Grid-stride loop over the words of frame 1; private counts, then a work-group tree
 * reduction in local memory and one atomic_add per candidate and group. */
__kernel void shift_cost(__global const uint *tb1,
                         __global const uint *eb1,
                         __global const uint *tb2,
                         __global const uint *eb2,
                         __global uint *counts,
                         const int h,
                         const int words,
                         const int cy,
                         const int cx)
{
    __local uint red[9 * WG];
    const int lid = get_local_id(0);
    const int nwords = h * words;
    uint c[9];
    for (int m = 0; m < 9; ++m)
        c[m] = 0u;
    for (int q = get_global_id(0); q < nwords; q += get_global_size(0)) {
        const uint e1 = eb1[q];
        if (e1 == 0u)
            continue;
        const uint t1 = tb1[q];
        const int y = q / words;
        const int s0 = (q - y * words) * 32 + cx - 1;
        for (int j = 0; j < 3; ++j) {
            const int yf = y + cy + j - 1;
            if (yf < 0 || yf >= h)
                continue;
            for (int i = 0; i < 3; ++i) {
                const uint t2 = fetch(tb2, yf, words, s0 + i);
                const uint e2 = fetch(eb2, yf, words, s0 + i);
                c[3 * j + i] += popcount((t1 ^ t2) & e1 & e2);
            }
        }
    }
    /* every work item reaches the barriers: no early return above */
    for (int m = 0; m < 9; ++m)
        red[m * WG + lid] = c[m];
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int span = WG / 2; span > 0; span >>= 1) {
        if (lid < span)
            for (int m = 0; m < 9; ++m)
                red[m * WG + lid] += red[m * WG + lid + span];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    for (int m = lid; m < 9; m += WG) {
        const uint v = red[m * WG];
        if (v)
            atomic_add(&counts[m], v);
    }
}
