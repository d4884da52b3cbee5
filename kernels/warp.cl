/*
 * warp.cl -- a frame resampled through a 3x3 matrix (hand-held alignment).
 * NumPy twin: hdrcl.core.warp (warp_rows); the equations are in its docstring.
 *
 *   (u, v, s) = M (x, y, 1),  (sx, sy) = (u / s, v / s)   reference -> frame coordinates
 *   a coordinate within SNAP of an integer is snapped to it
 *   out(x, y) = clamp(floor(sum_j wy_j (sum_i wx_i z(iy + j - 1, ix + i - 1)) + 1/2), 0, ZMAX)
 *   (separable: each tap row summed over x first, then the rows over y)
 *   with Keys' cubic weights (a = -1/2) of the fractions tx = sx - ix, ty = sy - iy.
 *   A tap contributes when its weight wx_i wy_j is not 0 (wx_i and wy_j both not 0).
 *   covered: s > 0 and every contributing tap inside the frame (else the codes are 0);
 *   valid: covered and every contributing tap valid in the source mask (when HAS_VALID).
 *   clipped: a channel with a contributing tap at or above CLIP_HI (fusion's clip level)
 *   is ZMAX: a clipped code is only a lower bound, and blending it with its unclipped
 *   neighbours would invent a believable mid-range value that fusion trusts.
 *   no ringing: a channel's value is held between its smallest and largest contributing
 *   tap (the cubic's over- and undershoot at a hard edge, one channel at a time, made
 *   single-pixel colour speckles beside clipped highlights and along fill edges).
 *
 * Speed (Intel CPU runtime, 24 MP RGB, a similarity): one work item per pixel,
 * coordinates and weights once per pixel, a pixel's channels as one float4 (one load
 * and one conversion per tap), and a pixel whose taps all lie inside the band takes
 * them without a test each. The runtime keeps this kernel scalar per work item (the
 * Site struct), which measured faster here than 8-wide across work items (gathers):
 * 0.42-0.46 s a frame, against 0.69 s for the same sums 8-wide and 0.95 s for the
 * kernel before (8-wide, per channel, a test per tap). PoCL: about the same as before
 * (1.9 s against 1.8 s).
 *
 * The source arrives as a band of rows (band_y0 .. band_y0 + band_h - 1) that the host
 * sized to hold every tap of the output strip; reads are clamped to the band anyway.
 *
 * Build options
 *   -DPIXEL_T=uchar|ushort  code type (default uchar)     -DZMAX=255|65535
 *   -DNCH=n                 channels per pixel (default 3) -DHAS_VALID=0|1
 *   -DTAPS=4|2              Keys cubic (4 x 4 taps, default) or bilinear (2 x 2)
 *   -DCLIP_HI=n             fusion's clip level (hdrcl.core.weights.clip_levels; default ZMAX)
 *
 * Arguments (units, layout)
 *   src      PIXEL_T [band_h][w][NCH]   source codes, channels interleaved
 *   srcvalid uchar [band_h][w]          1 = valid (ignored unless HAS_VALID)
 *   out      PIXEL_T [rows][w][NCH]     output strip, rows out_y0 .. out_y0 + rows - 1
 *   outvalid uchar [rows][w]            bit 0: valid, bit 1: covered
 *   m0..m8                              M row-major, float
 *
 * warp_grid: the same pixels on a grid, for a strip source that warps each strip of the
 * fusion as it is needed (hdrcl.core.align.stream) and for the sampling grid: output
 * pixel (x, r) is the warp at frame coordinates (x0 + x * step, out_y0 + r * step), so
 * a cropped strip (step 1) or every step-th pixel costs only the pixels asked for; the
 * value of a pixel is the same whichever kernel computes it.
 *   out      PIXEL_T [rows][out_w][NCH] outvalid uchar [rows][out_w]
 */
#ifndef PIXEL_T
#define PIXEL_T uchar
#endif
#ifndef ZMAX
#define ZMAX 255
#endif
#ifndef NCH
#define NCH 3
#endif
#ifndef HAS_VALID
#define HAS_VALID 0
#endif
#ifndef TAPS
#define TAPS 4 /* 4: Keys cubic, 2: bilinear */
#endif
#ifndef CLIP_HI
#define CLIP_HI ZMAX
#endif
#define KEYS_A (-0.5f)
#define SNAP (1.0f / 1024.0f)

inline float snap(const float c)
{
    const float r = rint(c);
    return fabs(c - r) < SNAP ? r : c;
}

inline void keys(const float t, float *wt)
{
#if TAPS == 4
    const float a = KEYS_A, t2 = t * t, t3 = t2 * t;
    wt[0] = a * (t3 - 2.0f * t2 + t);
    wt[1] = (a + 2.0f) * t3 - (a + 3.0f) * t2 + 1.0f;
    wt[2] = -(a + 2.0f) * t3 + (2.0f * a + 3.0f) * t2 - a * t;
    wt[3] = -a * (t3 - t2);
#else
    wt[0] = 1.0f - t;
    wt[1] = t;
#endif
}

/* A pixel's NCH codes as one float vector where NCH is 1, 3 or 4 (VEC_PATH), so that a
 * tap row's sum over x is TAPS vector multiply-adds. */
#if NCH == 1 || NCH == 3 || NCH == 4
#define VEC_PATH 1
#if NCH == 1
typedef float VF;
#define LOADV(p) ((float)(p)[0])
#define ZEROV 0.0f
#elif NCH == 3
/* 3 codes read as 4 (the 4th, the next pixel's first, ignored): one load and one
 * conversion; the inner path keeps a pixel right of the last tap for it */
typedef float4 VF;
#define LOADV(p) convert_float4(vload4(0, (p)))
#define ZEROV ((float4)(0.0f))
#define SPARE 1
#else
typedef float4 VF;
#define LOADV(p) convert_float4(vload4(0, (p)))
#define ZEROV ((float4)(0.0f))
#endif
#else
#define VEC_PATH 0
#endif
#ifndef SPARE
#define SPARE 0
#endif
#define CAT(a, b) CAT_(a, b)
#define CAT_(a, b) a##b

/* Where one output pixel samples: its coordinates, tap weights, first tap (x0, y0),
 * whether it is covered so far, and whether all its taps lie inside the band. */
typedef struct {
    float wx[TAPS], wy[TAPS];
    int x0, y0, covered, inner;
} Site;

inline Site site(const int x, const int y, const int h, const int w, const int band_y0, const int band_h,
                 const float m0, const float m1, const float m2, const float m3, const float m4,
                 const float m5, const float m6, const float m7, const float m8)
{
    Site t;
    const float fx = (float)x, fy = (float)y;
    const float u = m0 * fx + m1 * fy + m2;
    const float v = m3 * fx + m4 * fy + m5;
    const float s = m6 * fx + m7 * fy + m8;
    t.covered = s > 0.0f;
    t.inner = 0;
    t.x0 = t.y0 = 0;
    if (t.covered) {
        const float sx = snap(u / s), sy = snap(v / s);
        const float flx = floor(sx), fly = floor(sy);
        /* far-away coordinates: outside whatever the taps */
        if (fabs(flx) > 4.0f * (float)max(h, w) + 8.0f || fabs(fly) > 4.0f * (float)max(h, w) + 8.0f) {
            t.covered = 0;
        } else {
            keys(sx - flx, t.wx);
            keys(sy - fly, t.wy);
            t.x0 = (int)flx - (TAPS / 2 - 1);
            t.y0 = (int)fly - (TAPS / 2 - 1);
            t.inner = t.x0 >= 0 && t.x0 + TAPS <= w && t.y0 >= 0 && t.y0 + TAPS <= h
                      && t.y0 >= band_y0 && t.y0 + TAPS <= band_y0 + band_h;
        }
    }
    return t;
}

inline void put(__global PIXEL_T *out, __global uchar *outvalid, const size_t o, const float *acc,
                const float *bot, const float *top, const int covered, const int good)
{
    for (int k = 0; k < NCH; ++k) {
        const float z = !covered ? 0.0f : top[k] >= (float)CLIP_HI ? (float)ZMAX
                        : clamp(floor(acc[k] + 0.5f), bot[k], top[k]);
        out[o * NCH + k] = (PIXEL_T)z;
    }
    outvalid[o] = (uchar)((covered && good) | (covered << 1));
}

/* One output pixel: its codes and flags written. */
inline void pixel(const Site *t, __global const PIXEL_T *src, __global const uchar *srcvalid,
                  __global PIXEL_T *out, __global uchar *outvalid, const size_t o,
                  const int h, const int w, const int band_y0, const int band_h)
{
    float acc[NCH], top[NCH], bot[NCH]; /* the largest and smallest contributing tap per channel */
    for (int k = 0; k < NCH; ++k) {
        acc[k] = top[k] = 0.0f;
        bot[k] = (float)ZMAX;
    }
    int covered = t->covered, good = 1;
    if (covered && t->inner && t->x0 + TAPS + SPARE <= w) {
        /* every tap inside: no test per tap */
#if VEC_PATH
        VF sum = ZEROV, hi = ZEROV, lo = (VF)((float)ZMAX);
        for (int j = 0; j < TAPS; ++j) {
            const size_t q = (size_t)(t->y0 + j - band_y0) * w + t->x0;
            __global const PIXEL_T *p = src + q * NCH;
            VF row = ZEROV;
            for (int i = 0; i < TAPS; ++i) {
                const VF z = LOADV(p + i * NCH);
                row += t->wx[i] * z;
                hi = fmax(hi, z); /* every tap; the contributing ones only where it matters */
                lo = fmin(lo, z);
            }
            sum += t->wy[j] * row;
#if HAS_VALID
            if (t->wy[j] != 0.0f)
                for (int i = 0; i < TAPS; ++i)
                    good &= (t->wx[i] == 0.0f) | (srcvalid[q + i] != 0);
#endif
        }
#if NCH == 1
        acc[0] = sum; top[0] = hi; bot[0] = lo;
#else
        acc[0] = sum.s0; acc[1] = sum.s1; acc[2] = sum.s2;
        top[0] = hi.s0; top[1] = hi.s1; top[2] = hi.s2;
        bot[0] = lo.s0; bot[1] = lo.s1; bot[2] = lo.s2;
#if NCH == 4
        acc[3] = sum.s3; top[3] = hi.s3; bot[3] = lo.s3;
#endif
#endif
        /* A coordinate snapped to an integer leaves taps out (weight 0): the extremes are
         * then those of the contributing taps (rare) */
        int snapped = 0;
        for (int i = 0; i < TAPS; ++i)
            snapped |= (t->wx[i] == 0.0f) | (t->wy[i] == 0.0f);
        if (snapped) {
            for (int k = 0; k < NCH; ++k) {
                top[k] = 0.0f;
                bot[k] = (float)ZMAX;
            }
            for (int j = 0; j < TAPS; ++j) {
                const size_t q = (size_t)(t->y0 + j - band_y0) * w + t->x0;
                for (int i = 0; i < TAPS; ++i)
                    if (t->wx[i] != 0.0f && t->wy[j] != 0.0f)
                        for (int k = 0; k < NCH; ++k) {
                            const float z = (float)src[(q + i) * NCH + k];
                            top[k] = fmax(top[k], z);
                            bot[k] = fmin(bot[k], z);
                        }
            }
        }
#else
        for (int j = 0; j < TAPS; ++j) {
            const size_t q = (size_t)(t->y0 + j - band_y0) * w + t->x0;
            for (int k = 0; k < NCH; ++k) {
                float hk = 0.0f;
                for (int i = 0; i < TAPS; ++i) {
                    const float z = (float)src[(q + i) * NCH + k];
                    hk += t->wx[i] * z;
                    if (t->wx[i] != 0.0f && t->wy[j] != 0.0f) {
                        top[k] = fmax(top[k], z);
                        bot[k] = fmin(bot[k], z);
                    }
                }
                acc[k] += t->wy[j] * hk;
            }
#if HAS_VALID
            if (t->wy[j] != 0.0f)
                for (int i = 0; i < TAPS; ++i)
                    good &= (t->wx[i] == 0.0f) | (srcvalid[q + i] != 0);
#endif
        }
#endif
    } else if (covered) {
        /* near a border: a tap counts when its weight is not 0 */
        for (int j = 0; j < TAPS; ++j) {
            const int py = t->y0 + j;
            const int by = clamp(py - band_y0, 0, band_h - 1);
            float hk[NCH];
            for (int k = 0; k < NCH; ++k)
                hk[k] = 0.0f;
            for (int i = 0; i < TAPS; ++i) {
                if (t->wx[i] == 0.0f || t->wy[j] == 0.0f)
                    continue;
                const int px = t->x0 + i;
                if (px < 0 || px >= w || py < 0 || py >= h) {
                    covered = 0;
                    continue;
                }
                const size_t q = (size_t)by * w + px;
#if HAS_VALID
                good &= srcvalid[q] != 0;
#endif
                for (int k = 0; k < NCH; ++k) {
                    const float z = (float)src[q * NCH + k];
                    hk[k] += t->wx[i] * z;
                    top[k] = fmax(top[k], z);
                    bot[k] = fmin(bot[k], z);
                }
            }
            for (int k = 0; k < NCH; ++k)
                acc[k] += t->wy[j] * hk[k];
        }
    }
    put(out, outvalid, o, acc, bot, top, covered, good);
}

__kernel void warp(__global const PIXEL_T *restrict src,
                   __global const uchar *restrict srcvalid,
                   __global PIXEL_T *restrict out,
                   __global uchar *restrict outvalid,
                   const int h, const int w,
                   const int band_y0, const int band_h,
                   const int out_y0, const int rows,
                   const float m0, const float m1, const float m2,
                   const float m3, const float m4, const float m5,
                   const float m6, const float m7, const float m8)
{
    const int x = get_global_id(0);
    const int r = get_global_id(1);
    if (x >= w || r >= rows)
        return;
    const Site a = site(x, out_y0 + r, h, w, band_y0, band_h, m0, m1, m2, m3, m4, m5, m6, m7, m8);
    pixel(&a, src, srcvalid, out, outvalid, (size_t)r * w + x, h, w, band_y0, band_h);
}

__kernel void warp_grid(__global const PIXEL_T *restrict src,
                        __global const uchar *restrict srcvalid,
                        __global PIXEL_T *restrict out,
                        __global uchar *restrict outvalid,
                        const int h, const int w,
                        const int band_y0, const int band_h,
                        const int out_y0, const int rows,
                        const int x0, const int out_w, const int step,
                        const float m0, const float m1, const float m2,
                        const float m3, const float m4, const float m5,
                        const float m6, const float m7, const float m8)
{
    const int x = get_global_id(0);
    const int r = get_global_id(1);
    if (x >= out_w || r >= rows)
        return;
    const Site a = site(x0 + x * step, out_y0 + r * step, h, w, band_y0, band_h, m0, m1, m2, m3, m4, m5, m6, m7,
                        m8);
    pixel(&a, src, srcvalid, out, outvalid, (size_t)r * out_w + x, h, w, band_y0, band_h);
}
