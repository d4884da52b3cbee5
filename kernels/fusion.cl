/*
 * fusion.cl -- per-pixel fusion of a bracket into a radiance map
 * (Debevec & Malik 1997, eq. 6). NumPy twin: hdrcl.reference.fuse.
 *
 *   ln E = sum_j w(Z_j) (g_c(Z_j) - ln dt_j) / sum_j w(Z_j)
 *
 * Two kernels share one strip of codes:
 *
 *   fuse      the fast path. Each work item takes 4 pixels (4*NCH consecutive values,
 *             so every lane's channel is known at compile time), loads them as
 *             uchar4/ushort4 vectors and makes one 8-byte gather per sample from a
 *             table per frame that folds weight and log exposure together:
 *             lut[p][c][z] = (w(z)(g_c(z) - ln dt_p)/ln 2, w(z)). One division and one
 *             exp2 per value, none per sample. A value whose
 *             weights sum to zero is written as -1 (impossible radiance) and raises a
 *             flag (a plain store of 1: no atomics on the fast path).
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

#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
#define PIXEL4 CAT(PIXEL_T, 4)
#define LOAD4(i, p) vload4((i), (p))

#ifdef HAS_VALID
#define MASK(v, ok) select((float4)0.0f, (v), (ok))
#else
#define MASK(v, ok) (v)
#endif

/* Contribution of one 4-lane vector of codes whose lanes have channels c0..c3: one
 * float2 gather (weighted log exposure, weight) per lane. */
#define GATHER(z, c0, c1, c2, c3, l, num, den, ok)                                   \
    do {                                                                             \
        const float2 t0_ = l[(c0) * LEVELS + (z).s0], t1_ = l[(c1) * LEVELS + (z).s1]; \
        const float2 t2_ = l[(c2) * LEVELS + (z).s2], t3_ = l[(c3) * LEVELS + (z).s3]; \
        num += MASK((float4)(t0_.x, t1_.x, t2_.x, t3_.x), (ok));                     \
        den += MASK((float4)(t0_.y, t1_.y, t2_.y, t3_.y), (ok));                     \
    } while (0)

inline float4 finish(const float4 num, const float4 den, __global uint *counts)
{
    const int4 zero = den <= 0.0f;
    if (any(zero))
        counts[3] = 1u; /* a flag, not a count: every writer stores the same value */
    return select(exp2(num / den), (float4)(-1.0f), zero);
}

/* Scalar version of one value, for the ragged end of a strip. */
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
    if (i0 >= npix)
        return;
    if (i0 + 4 > npix) { /* ragged end */
        for (int i = i0; i < npix; ++i)
            for (int c = 0; c < NCH; ++c)
                out[(size_t)i * NCH + c] = one_value(frames, valid, lut, counts, i, c, nframes, levels,
                                                     plane, vplane);
        return;
    }
    const size_t v0 = (size_t)i0 * NCH;
    float4 na = 0.0f;
    float4 da = 0.0f;
#if NCH == 3
    float4 nb = 0.0f, nc = 0.0f, db = 0.0f, dc = 0.0f;
#endif
    for (int p = 0; p < nframes; ++p) {
        __global const PIXEL_T *f = frames + (size_t)p * plane + v0;
        __global const float2 *l = lut + p * NCH * LEVELS;
#ifdef HAS_VALID
        const int4 m = convert_int4(vload4(0, valid + (size_t)p * vplane + i0)) != 0;
#else
        const int4 m = (int4)(-1);
#endif
#if NCH == 3
        /* values 0..11 = pixels 0..3 x RGB: lanes (R G B R) (G B R G) (B R G B) */
        const PIXEL4 a = LOAD4(0, f), b = LOAD4(1, f), c = LOAD4(2, f);
        GATHER(a, 0, 1, 2, 0, l, na, da, m.s0001);
        GATHER(b, 1, 2, 0, 1, l, nb, db, m.s1122);
        GATHER(c, 2, 0, 1, 2, l, nc, dc, m.s2333);
#else
        const PIXEL4 a = LOAD4(0, f);
        GATHER(a, 0, 0, 0, 0, l, na, da, m);
#endif
    }
    __global float *o = out + v0;
    vstore4(finish(na, da, counts), 0, o);
#if NCH == 3
    vstore4(finish(nb, db, counts), 1, o);
    vstore4(finish(nc, dc, counts), 2, o);
#endif
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
