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
 *   grey        g = 1000 grey (integers for integer codes)        one frame per launch
 *   weight_sum  wk = W_k, wsum = (first ? 0 : wsum) + W_k       one frame per launch
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
 *   -DINTEGER_CODES               uchar or ushort codes: the grey's Laplacian and the saturation
 *                                 in integers (exact)
 *   -DSAT_T=int|long              integer type of the saturation's sums (long for ushort)
 *
 * Arguments (units, layout): images are row-major, channels interleaved, float32
 *   codes   PIXEL_T [h * w * NCH]  one frame's window
 *   valid   uchar [h * w]           read only with -DHAS_VALID
 *   g       int|float [h * w]       1000 x grey of the frame's codes
 *   wk      float [h * w]           W_k of one frame (dimensionless; kept from weight_sum
 *                                   to load: computing it again cost more than storing it)
 *   wsum    float [h * w]           sum of the frames' W_k
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

/* OpenCV's BORDER_REFLECT_101 for p at most 2 outside [0, n) -- all the kernels need --
 * with n >= 1; written without a loop (the CPU runtime then vectorises across work items). */
static int reflect101(int p, const int n)
{
    p = abs(p);
    p = p >= n ? 2 * n - 2 - p : p;
    p = abs(p);
    return n == 1 ? 0 : p;
}

#ifdef INTEGER_CODES
typedef int lap_t;
#else
typedef float lap_t;
#endif
#ifndef SAT_T
#define SAT_T long
#endif

/* The grey scaled by 1000 (299 R + 587 G + 114 B; 1000 Y for one channel): integers for
 * integer codes, so its Laplacian is exact and a flat or linear ramp of codes has exactly
 * no contrast (as in the float64 twin; OpenCV's float32 grey leaves noise there). */
__kernel void grey(__global const PIXEL_T *codes, __global lap_t *g, const int w, const int h)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h)
        return;
    const size_t p = (size_t)y * w + x;
#if NCH == 3
    g[p] = 299 * (lap_t)codes[p * 3] + 587 * (lap_t)codes[p * 3 + 1] + 114 * (lap_t)codes[p * 3 + 2];
#else
    g[p] = 1000 * (lap_t)codes[p];
#endif
}

static float powe(const float v, const float e)
{
    return e == 1.0f ? v : pow(v, e);
}

/* W_k - 1e-12 at (x, y); px receives I_k there. */
static float mertens_weight(__global const PIXEL_T *codes, __global const lap_t *g, const int x, const int y,
                            const int w, const int h, const float scale, const float wc, const float ws,
                            const float we, const float inv2s2, float *px)
{
    const size_t i = ((size_t)y * w + x) * NCH;
    const size_t row = (size_t)y * w;
    const lap_t l4 = g[(size_t)reflect101(y - 1, h) * w + x] + g[(size_t)reflect101(y + 1, h) * w + x]
                   + g[row + reflect101(x - 1, w)] + g[row + reflect101(x + 1, w)] - 4 * g[row + x];
    const float lap = (float)l4 * (scale * 0.001f);
    float e2 = 0.0f; /* prod_c exp(-d_c^2 inv2s2) as one exp of the sum */
    for (int c = 0; c < NCH; c++) {
        px[c] = (float)codes[i + c] * scale;
        const float d = px[c] - 0.5f;
        e2 += d * d;
    }
    const float wexp = exp(-e2 * inv2s2);
    float out = powe(fabs(lap), wc);
#if NCH == 3
    /* sum_c (c - mean)^2 = (3 sum c^2 - (sum c)^2) / 3: exact in integers, so a grey
     * pixel has exactly no saturation (as in the twin) */
#ifdef INTEGER_CODES
    const SAT_T c0 = codes[i], c1 = codes[i + 1], c2 = codes[i + 2];
    const SAT_T s1 = c0 + c1 + c2;
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

__kernel void weight_sum(__global const PIXEL_T *codes, __global const lap_t *g, VALID_PARAM __global float *wk,
                         __global float *wsum,
                         const int w, const int h, const float scale, const float wc, const float ws, const float we,
                         const float inv2s2, const int first)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h)
        return;
    const size_t p = (size_t)y * w + x;
    float px[NCH];
    float v = IS_VALID(p) ? mertens_weight(codes, g, x, y, w, h, scale, wc, ws, we, inv2s2, px) : 0.0f;
    v += EPS_W;
    wk[p] = v;
    wsum[p] = first ? v : wsum[p] + v;
}

__kernel void load(__global const PIXEL_T *codes, __global const float *wk, __global const float *wsum,
                   __global float *img, __global float *wn, const int w, const int h, const float scale)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h)
        return;
    const size_t p = (size_t)y * w + x;
    wn[p] = wk[p] / wsum[p];
    for (int c = 0; c < NCH; c++)
        img[p * NCH + c] = (float)codes[p * NCH + c] * scale;
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

/* Taps of pyrUp along one dimension at fine index y (coarse length n): the coarse
 * indices and weights (kernel x 2 / 16) of the zero-stuffed signal of length 2n under
 * reflect-101: y = 2i takes i-1, i, i+1 (1, 6, 1 / 8; i-1 of i = 0 is 1, i+1 of i = n-1
 * is n-1), y = 2i+1 takes i, i+1 (4, 4 / 8; i+1 of i = n-1 is n-1). */
static int up_taps(const int y, const int n, int *idx, float *wt)
{
    const int i = y >> 1;
    const int hi = min(i + 1, n - 1);
    if (y & 1) {
        idx[0] = i;
        idx[1] = hi;
        wt[0] = wt[1] = 0.5f;
        return 2;
    }
    idx[0] = i == 0 ? min(1, n - 1) : i - 1;
    idx[1] = i;
    idx[2] = hi;
    wt[0] = wt[2] = 0.125f;
    wt[1] = 0.75f;
    return 3;
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
