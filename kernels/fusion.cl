/*
 * fusion.cl -- per-pixel fusion of a bracket into a radiance map
 * (Debevec & Malik 1997, eq. 6). NumPy twin: hdrcl.reference.fuse.
 *
 *   ln E = sum_j w(Z_j) (g_c(Z_j) - ln dt_j) / sum_j w(Z_j)
 *
 * Three kernels share one strip of codes:
 *
 *   fuse      the fast path. Each work item takes 4 pixels (4*NCH consecutive values,
 *             so every value's channel is known at compile time) and makes one 8-byte
 *             load per sample from a table per frame that folds weight and log
 *             exposure together: lut[p][c][z] = (w(z)(g_c(z) - ln dt_p)/ln 2, w(z)),
 *             accumulated per value in private float2s. One division and one exp2
 *             per value, none per sample. A value whose
 *             weights sum to zero is written as -1 (impossible radiance) and raises a
 *             flag (a plain store of 1: no atomics on the fast path).
 *   fuse_tail the last npix % 4 pixels, one value at a time, same arithmetic.
 *   fuse_fix  run only when fuse raised the flag: one work item per pixel applies
 *             the twin's rule to them. Clipped high (the shortest valid frame reads
 *             2Z >= L) -> g_c(Zmax) - ln dt_shortest; otherwise black ->
 *             g_c(Zmin) - ln dt_longest; valid in no frame -> 0.
 *
 * Frames are ordered by increasing exposure.
 *
 * Build options
 *   -DPIXEL_T=uchar|ushort  integer type of the codes (default uchar)
 *   -DNCH=1|3               channels per pixel (default 3)
 *   -DHAS_VALID             per-frame validity masks are given
 *   -DLEVELS=256|65536      code values (must equal the levels argument)
 *   -DNFRAMES=P             optional: frame count fixed at build time (must equal the
 *                           nframes argument): the compiler then unrolls the frame loop
 *
 * Arguments (units, layout)
 *   frames   PIXEL_T [P][plane]  codes of a strip: frame p starts at p*plane, pixels
 *                                row-major, channels interleaved (i*NCH + c)
 *   valid    uchar [P][vplane]   1 where frame p measures pixel i (HAS_VALID only)
 *   lut      float2 [P][NCH][L]  (w(z) (g_c(z) - ln dt_p) / ln 2, w(z)): log2 exposure
 *                                units times weight, and the dimensionless weight
 *   hi, lo   float [P][NCH]      (g_c(L-1) - ln dt_p) / ln 2 and (g_c(0) - ln dt_p) / ln 2
 *   out      float [npix*NCH]    linear relative radiance E, channels interleaved
 *   counts   uint [4]            clipped high, black, valid nowhere (counts); [3] is the
 *                                fast path's zero-weight flag, cleared by the host
 *   npix                         pixels in this strip
 *   nframes, levels              P, L
 *   plane, vplane                elements between frames in `frames` and `valid`
 */
#ifndef PIXEL_T
#define PIXEL_T uchar
#endif
#ifndef NCH
#define NCH 3
#endif
/* Code values: fixed by the pixel type, so table offsets fold into constants. */
#ifndef LEVELS
#define LEVELS 256
#endif

/* Frame count: a compile-time constant when the host gives -DNFRAMES (the frame loop
 * then unrolls), else the nframes argument. */
#ifdef NFRAMES
#define FRAME_COUNT NFRAMES
#else
#define FRAME_COUNT nframes
#endif

/* Value k of a work item's 4 pixels (channel k % NCH, pixel k / NCH, both constants)
 * adds its sample of frame p to its accumulator a<k>; a masked-out sample adds 0. */
#ifdef HAS_VALID
#define SAMPLE(k) a##k += m[(k) / NCH] ? l[((k) % NCH) * LEVELS + f[k]] : (float2)(0.0f)
#else
#define SAMPLE(k) a##k += l[((k) % NCH) * LEVELS + f[k]]
#endif

/* exp2(num / den), or -1 (impossible radiance, for fuse_fix) where the weights sum to zero. */
inline float4 quotient(const float4 num, const float4 den)
{
    return select(exp2(num / den), (float4)(-1.0f), den <= 0.0f);
}

/* Scalar version of one value, for the ragged end of a strip (fuse_tail). */
inline float one_value(__global const PIXEL_T *frames, __global const uchar *valid,
                       __global const float2 *lut, __global uint *counts, const int i, const int c,
                       const int nframes, const int levels, const int plane, const int vplane)
{
    float num = 0.0f, den = 0.0f;
    for (int p = 0; p < nframes; ++p) {
#ifdef HAS_VALID
        if (!valid[(size_t)p * vplane + i])
            continue;
#endif
        const int z = frames[(size_t)p * plane + (size_t)i * NCH + c];
        const float2 t = lut[(p * NCH + c) * levels + z];
        num += t.x;
        den += t.y;
    }
    if (den > 0.0f)
        return exp2(num / den);
    counts[3] = 1u;
    return -1.0f;
}

/* The fast path. Per sample: one scalar load of the code, one 8-byte load from the
 * folded table (its index is the code plus a constant), one float2 add into that
 * value's own accumulator. Scalar loads and private accumulators, rather than vector
 * loads and lane shuffles, keep the inner loop at a few instructions per sample on CPU
 * drivers; summation order is that of the frames, as in the twin. */
__kernel void fuse(__global const PIXEL_T *frames,
                   __global const uchar *valid,
                   __global const float2 *lut,
                   __global float *out,
                   __global uint *counts,
                   const int npix,
                   const int nframes,
                   const int levels,
                   const int plane,
                   const int vplane)
{
    const int q = get_global_id(0);
    const int i0 = q * 4; /* first pixel of this work item */
    if (i0 + 4 > npix) /* the last npix % 4 pixels are fuse_tail's */
        return;
    const size_t v0 = (size_t)i0 * NCH;
    float2 a0 = 0.0f, a1 = 0.0f, a2 = 0.0f, a3 = 0.0f;
#if NCH == 3
    float2 a4 = 0.0f, a5 = 0.0f, a6 = 0.0f, a7 = 0.0f, a8 = 0.0f, a9 = 0.0f, a10 = 0.0f, a11 = 0.0f;
#endif
    for (int p = 0; p < FRAME_COUNT; ++p) {
        __global const PIXEL_T *f = frames + (size_t)p * plane + v0;
        __global const float2 *l = lut + p * NCH * LEVELS;
#ifdef HAS_VALID
        __global const uchar *m = valid + (size_t)p * vplane + i0;
#endif
        SAMPLE(0); SAMPLE(1); SAMPLE(2); SAMPLE(3);
#if NCH == 3
        SAMPLE(4); SAMPLE(5); SAMPLE(6); SAMPLE(7); SAMPLE(8); SAMPLE(9); SAMPLE(10); SAMPLE(11);
#endif
    }
    /* One flag store per work item at most: values whose weights sum to zero. */
    __global float *o = out + v0;
    int4 zero = (float4)(a0.y, a1.y, a2.y, a3.y) <= 0.0f;
    vstore4(quotient((float4)(a0.x, a1.x, a2.x, a3.x), (float4)(a0.y, a1.y, a2.y, a3.y)), 0, o);
#if NCH == 3
    zero |= (float4)(a4.y, a5.y, a6.y, a7.y) <= 0.0f;
    zero |= (float4)(a8.y, a9.y, a10.y, a11.y) <= 0.0f;
    vstore4(quotient((float4)(a4.x, a5.x, a6.x, a7.x), (float4)(a4.y, a5.y, a6.y, a7.y)), 1, o);
    vstore4(quotient((float4)(a8.x, a9.x, a10.x, a11.x), (float4)(a8.y, a9.y, a10.y, a11.y)), 2, o);
#endif
    if (any(zero))
        counts[3] = 1u; /* a flag, not a count: every writer stores the same value */
}

/* The last npix % 4 pixels of a strip (fuse takes whole groups of 4): one work item per
 * pixel from `first`. A separate kernel keeps the ragged end's loops out of fuse, where
 * they stop some drivers from vectorising across work items. */
__kernel void fuse_tail(__global const PIXEL_T *frames,
                        __global const uchar *valid,
                        __global const float2 *lut,
                        __global float *out,
                        __global uint *counts,
                        const int npix,
                        const int nframes,
                        const int levels,
                        const int plane,
                        const int vplane,
                        const int first)
{
    const int i = first + (int)get_global_id(0);
    if (i >= npix)
        return;
    for (int c = 0; c < NCH; ++c)
        out[(size_t)i * NCH + c] = one_value(frames, valid, lut, counts, i, c, nframes, levels, plane, vplane);
}

__kernel void fuse_fix(__global const PIXEL_T *frames,
                       __global const uchar *valid,
                       __global const float *hi,
                       __global const float *lo,
                       __global float *out,
                       __global uint *counts,
                       const int npix,
                       const int nframes,
                       const int levels,
                       const int plane,
                       const int vplane)
{
    const int i = get_global_id(0);
    if (i >= npix)
        return;
    for (int c = 0; c < NCH; ++c) {
        const size_t v = (size_t)i * NCH + c;
        if (out[v] >= 0.0f)
            continue;
        int first = -1;
        int last = -1;
        for (int p = 0; p < nframes; ++p) {
#ifdef HAS_VALID
            if (!valid[(size_t)p * vplane + i])
                continue;
#endif
            if (first < 0)
                first = p;
            last = p;
        }
        float e;
        if (first < 0) {
            e = 0.0f;
            atomic_inc(&counts[2]);
        } else if (2 * (int)frames[(size_t)first * plane + v] >= levels) {
            e = exp2(hi[first * NCH + c]);
            atomic_inc(&counts[0]);
        } else {
            e = exp2(lo[last * NCH + c]);
            atomic_inc(&counts[1]);
        }
        out[v] = e;
    }
}
