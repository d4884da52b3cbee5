/*
 * mertens.cl -- exposure fusion (Mertens, Kautz & Van Reeth 2007) as OpenCV's
 * MergeMertens computes it. NumPy twin: hdrcl.core.mertens (float64; the equations
 * are written out in its docstring). Host: hdrcl.cl.mertens.MertensProcessor.
 *
 * Per frame k, from its codes I = code * scale in [0, 1]:
 *   W_k = |lap(grey)|^wc * sqrt(sum_c (I_c - mean)^2)^ws * prod_c exp(-(I_c - 0.5)^2 inv2s2)^we
 *         + 1e-12       (0 before the 1e-12 where the frame is invalid; NCH == 1: no
 *                        saturation term), grey = 0.299 R + 0.587 G + 0.114 B,
 *                        lap = 4-neighbour Laplacian, border reflect-101, taken of each
 *                        channel's codes (exact in integers) and then weighted as grey:
 *                        where the codes are flat or a linear ramp the contrast is exactly 0
 *                        (OpenCV's float32 grey leaves rounding noise there, ~1e-8)
 *   V_k = W_k / sum_j W_j
 * then the Laplacian pyramid of each I_k weighted by the Gaussian pyramid of V_k, summed
 * over k, collapsed. pyr_down is OpenCV's pyrDown (5x5 [1 4 6 4 1]/16, reflect-101,
 * (n + 1) / 2); up() is its pyrUp: the coarse image zero-stuffed to length 2n, reflect-101
 * there, the same kernel x 4, cut to the finer size (2n or 2n - 1).
 *
 * Kernels (2-D ranges: dimension 0 the column x, dimension 1 the row y, each rounded up
 * to the work-group size; every kernel returns for x >= w or y >= h):
 *   weight_sum  wsum = (first ? 0 : wsum) + W_k                 one frame per launch
 *   load        img = I_k, wn = W_k / wsum                       level 0 of both pyramids
 *   pyr_down1, pyr_downc   one level of a 1- or NCH-channel Gaussian pyramid
 *   blend       acc = (first ? 0 : acc) + (g - up(gc)) * wl     a Laplacian level, weighted
 *   blend_top   acc = (first ? 0 : acc) + g * wl                the coarsest level
 *   collapse    dst += up(src)                                  the pyramid's sum
 *
 * Build options
 *   -DPIXEL_T=uchar|ushort|float  type of the frame codes (default uchar)
 *   -DNCH=1|3                     channels per pixel (default 3)
 *   -DHAS_VALID                   a per-pixel validity mask (uchar, 0 invalid) is read
 *   -DINTEGER_CODES               uchar or ushort codes: the Laplacian in integers (exact)
 *
 * Arguments (units, layout): images are row-major, channels interleaved, float32
 *   codes   PIXEL_T [h * w * NCH]  one frame's window
 *   valid   uchar [h * w]           read only with -DHAS_VALID
 *   wsum    float [h * w]           sum of the frames' W_k (dimensionless)
 *   img     float [h * w * NCH]     I_k in [0, 1]
 *   wn      float [h * w]           V_k in [0, 1]
 *   g, gc   float [h*w*NCH], [ch*cw*NCH]   a Gaussian level and the next coarser one
 *   wl      float [h * w]           the weights' Gaussian level
 *   acc     float [h * w * NCH]     the blended level (and, collapsed, the result)
 *   w, h, cw, ch                    sizes of the level and of the coarser one (pixels)
 *   scale                           1/255, 1/65535 or 1 (float codes)
 *   wc, ws, we                      exponents of contrast, saturation, well-exposedness
 *   inv2s2                          1 / (2 sigma^2), sigma in [0, 1] units (0.2: 12.5)
 *   first                           1: the first frame overwrites instead of adding
 */
#ifndef PIXEL_T
#define PIXEL_T uchar
#endif
#ifndef NCH
#define NCH 3
#endif

#define EPS_W 1e-12f

static int reflect101(int p, const int n)
{
    if (n == 1)
        return 0;
    while (p < 0 || p >= n)
        p = p < 0 ? -p : 2 * n - 2 - p;
    return p;
}

#ifdef INTEGER_CODES
typedef int lap_t;
#else
typedef float lap_t;
#endif

/* 4-neighbour Laplacian of channel c's codes: exact for integer codes, so that a flat
 * or linear ramp of codes has exactly no contrast (as in the float64 twin). */
static lap_t lap_at(__global const PIXEL_T *codes, const int x, const int y, const int w, const int h, const int c)
{
    const int xl = reflect101(x - 1, w), xr = reflect101(x + 1, w);
    const int yu = reflect101(y - 1, h), yd = reflect101(y + 1, h);
    return (lap_t)codes[((size_t)yu * w + x) * NCH + c] + (lap_t)codes[((size_t)yd * w + x) * NCH + c]
         + (lap_t)codes[((size_t)y * w + xl) * NCH + c] + (lap_t)codes[((size_t)y * w + xr) * NCH + c]
         - 4 * (lap_t)codes[((size_t)y * w + x) * NCH + c];
}

static float powe(const float v, const float e)
{
    return e == 1.0f ? v : pow(v, e);
}

/* W_k - 1e-12 at (x, y); px receives I_k there. */
static float mertens_weight(__global const PIXEL_T *codes, const int x, const int y, const int w, const int h,
                            const float scale, const float wc, const float ws, const float we,
                            const float inv2s2, float *px)
{
    const size_t i = ((size_t)y * w + x) * NCH;
#if NCH == 3
    const float lap = (0.299f * (float)lap_at(codes, x, y, w, h, 0) + 0.587f * (float)lap_at(codes, x, y, w, h, 1)
                     + 0.114f * (float)lap_at(codes, x, y, w, h, 2)) * scale;
#else
    const float lap = (float)lap_at(codes, x, y, w, h, 0) * scale;
#endif
    float wexp = 1.0f;
    for (int c = 0; c < NCH; c++) {
        px[c] = (float)codes[i + c] * scale;
        const float d = px[c] - 0.5f;
        wexp *= exp(-d * d * inv2s2);
    }
    float out = powe(fabs(lap), wc);
#if NCH == 3
    /* sum_c (c - mean)^2 = (3 sum c^2 - (sum c)^2) / 3: exact in integers, so a grey
     * pixel has exactly no saturation (as in the twin) */
#ifdef INTEGER_CODES
    const long c0 = codes[i], c1 = codes[i + 1], c2 = codes[i + 2];
    const long s1 = c0 + c1 + c2;
    const float s = (float)(3 * (c0 * c0 + c1 * c1 + c2 * c2) - s1 * s1) * (1.0f / 3.0f);
    out *= powe(sqrt(s) * scale, ws);
#else
    const float mean = (px[0] + px[1] + px[2]) / 3.0f;
    const float s = (px[0] - mean) * (px[0] - mean) + (px[1] - mean) * (px[1] - mean) + (px[2] - mean) * (px[2] - mean);
    out *= powe(sqrt(s), ws);
#endif
#endif
    return out * powe(wexp, we);
}

/* valid is an argument with or without -DHAS_VALID (the host then passes any buffer). */
#define VALID_PARAM __global const uchar *valid,
#ifdef HAS_VALID
#define IS_VALID(i) (valid[i] != 0)
#else
#define IS_VALID(i) 1
#endif

__kernel void weight_sum(__global const PIXEL_T *codes, VALID_PARAM __global float *wsum, const int w, const int h,
                         const float scale, const float wc, const float ws, const float we, const float inv2s2,
                         const int first)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h)
        return;
    const size_t p = (size_t)y * w + x;
    float px[NCH];
    float wk = IS_VALID(p) ? mertens_weight(codes, x, y, w, h, scale, wc, ws, we, inv2s2, px) : 0.0f;
    wk += EPS_W;
    wsum[p] = first ? wk : wsum[p] + wk;
}

__kernel void load(__global const PIXEL_T *codes, VALID_PARAM __global const float *wsum, __global float *img,
                   __global float *wn, const int w, const int h, const float scale, const float wc, const float ws,
                   const float we, const float inv2s2)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h)
        return;
    const size_t p = (size_t)y * w + x;
    float px[NCH];
    float wk = mertens_weight(codes, x, y, w, h, scale, wc, ws, we, inv2s2, px);
    if (!IS_VALID(p))
        wk = 0.0f;
    wn[p] = (wk + EPS_W) / wsum[p];
    for (int c = 0; c < NCH; c++)
        img[p * NCH + c] = px[c];
}

#define K5(i) ((i) == 2 ? 6.0f : ((i) == 1 || (i) == 3) ? 4.0f : 1.0f)

#define PYR_DOWN(NAME, C)                                                                          \
__kernel void NAME(__global const float *src, __global float *dst, const int sw, const int sh,     \
                   const int dw, const int dh)                                                     \
{                                                                                                  \
    const int x = get_global_id(0), y = get_global_id(1);                                          \
    if (x >= dw || y >= dh)                                                                        \
        return;                                                                                    \
    float acc[C];                                                                                  \
    for (int c = 0; c < C; c++)                                                                    \
        acc[c] = 0.0f;                                                                             \
    int xs[5];                                                                                     \
    for (int j = 0; j < 5; j++)                                                                    \
        xs[j] = reflect101(2 * x + j - 2, sw);                                                     \
    for (int i = 0; i < 5; i++) {                                                                  \
        const size_t row = (size_t)reflect101(2 * y + i - 2, sh) * sw;                             \
        float r[C];                                                                                \
        for (int c = 0; c < C; c++)                                                                \
            r[c] = 0.0f;                                                                           \
        for (int j = 0; j < 5; j++)                                                                \
            for (int c = 0; c < C; c++)                                                            \
                r[c] += K5(j) * src[(row + xs[j]) * C + c];                                        \
        for (int c = 0; c < C; c++)                                                                \
            acc[c] += K5(i) * r[c];                                                                \
    }                                                                                              \
    const size_t o = ((size_t)y * dw + x) * C;                                                     \
    for (int c = 0; c < C; c++)                                                                    \
        dst[o + c] = acc[c] * (1.0f / 256.0f);                                                     \
}

PYR_DOWN(pyr_down1, 1)
PYR_DOWN(pyr_downc, NCH)

/* Taps of pyrUp along one dimension at fine index y (coarse length n): 2 or 3 indices
 * into the coarse row or column and their weights (kernel x 2 / 16). */
static int up_taps(const int y, const int n, int *idx, float *wt)
{
    int m = 0;
    for (int t = 0; t < 5; t++) {
        const int j = reflect101(y + t - 2, 2 * n);
        if ((j & 1) == 0) {
            idx[m] = j >> 1;
            wt[m] = K5(t) * 0.125f;
            m++;
        }
    }
    return m;
}

static void up(__global const float *gc, const int x, const int y, const int cw, const int ch, float *out)
{
    int iy[3], ix[3];
    float wy[3], wx[3];
    const int ny = up_taps(y, ch, iy, wy), nx = up_taps(x, cw, ix, wx);
    for (int c = 0; c < NCH; c++)
        out[c] = 0.0f;
    for (int a = 0; a < ny; a++) {
        const size_t row = (size_t)iy[a] * cw;
        float r[NCH];
        for (int c = 0; c < NCH; c++)
            r[c] = 0.0f;
        for (int b = 0; b < nx; b++)
            for (int c = 0; c < NCH; c++)
                r[c] += wx[b] * gc[(row + ix[b]) * NCH + c];
        for (int c = 0; c < NCH; c++)
            out[c] += wy[a] * r[c];
    }
}

__kernel void blend(__global float *acc, __global const float *g, __global const float *gc, __global const float *wl,
                    const int w, const int h, const int cw, const int ch, const int first)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h)
        return;
    const size_t p = (size_t)y * w + x;
    float u[NCH];
    up(gc, x, y, cw, ch, u);
    const float v = wl[p];
    for (int c = 0; c < NCH; c++) {
        const float t = (g[p * NCH + c] - u[c]) * v;
        acc[p * NCH + c] = first ? t : acc[p * NCH + c] + t;
    }
}

__kernel void blend_top(__global float *acc, __global const float *g, __global const float *wl, const int w,
                        const int h, const int first)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h)
        return;
    const size_t p = (size_t)y * w + x;
    const float v = wl[p];
    for (int c = 0; c < NCH; c++) {
        const float t = g[p * NCH + c] * v;
        acc[p * NCH + c] = first ? t : acc[p * NCH + c] + t;
    }
}

__kernel void collapse(__global float *dst, __global const float *src, const int w, const int h, const int cw,
                       const int ch)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h)
        return;
    const size_t p = (size_t)y * w + x;
    float u[NCH];
    up(src, x, y, cw, ch, u);
    for (int c = 0; c < NCH; c++)
        dst[p * NCH + c] += u[c];
}
