/*
 * fisheye.cl -- the per-pixel steps of a fisheye luminance map (N x N pictures).
 * NumPy twins (float64): hdrcl.core.fisheye_math.equisolid_to_equidistant and
 * hdrcl.core.fisheye_math.vignetting_factors / apply_vignetting, where the equations
 * are stated.
 *
 * project_equisolid: output pixel (i, j), centre u = (j + 1/2)/N - 1/2,
 *   v = (i + 1/2)/N - 1/2 (picture widths); rd = |(u, v)|; inside the view iff
 *   (2j+1-N)^2 + (2i+1-N)^2 <= N^2 (integers: exact); there the source is read at the
 *   equisolid radius rs = sin(pi rd / 2) / sqrt(2) along the same direction, bilinear,
 *   edge pixels repeated; outside it is 0.
 * vignette: x = j, y = N - 1 - i (Radiance pcomb), r = |(x - xc, y - yc)| / radius,
 *   out = in / (a0 + a1 r + ... + a8 r^8) (Horner).
 *
 * Arguments (units, layout)
 *   src, dst   float [N * N * nch]   rows top to bottom, channels interleaved
 *   n, nch                          picture side; 1 or 3 channels
 *   coeffs     float [9]            a0 .. a8
 *   xc, yc, radius                  pixels (Radiance coordinates)
 */

static float fetch(__global const float *src, int x, int y, const int n, const int nch, const int c)
{
    x = clamp(x, 0, n - 1);
    y = clamp(y, 0, n - 1);
    return src[((size_t)y * n + x) * nch + c];
}

__kernel void project_equisolid(__global const float *src, __global float *dst, const int n, const int nch)
{
    const int gid = get_global_id(0);
    if (gid >= n * n)
        return;
    const int i = gid / n;
    const int j = gid - i * n;
    const long ki = 2 * i + 1 - n, kj = 2 * j + 1 - n;
    __global float *out = dst + (size_t)gid * nch;
    if (ki * ki + kj * kj > (long)n * n) {
        for (int c = 0; c < nch; ++c)
            out[c] = 0.0f;
        return;
    }
    const float u = ((float)j + 0.5f) / (float)n - 0.5f;
    const float v = ((float)i + 0.5f) / (float)n - 0.5f;
    const float rd = hypot(u, v);
    const float scale = rd > 0.0f ? sin(M_PI_F * 0.5f * rd) / (M_SQRT2_F * rd) : M_PI_F / (2.0f * M_SQRT2_F);
    const float xs = clamp((0.5f + u * scale) * (float)n - 0.5f, 0.0f, (float)(n - 1));
    const float ys = clamp((0.5f + v * scale) * (float)n - 0.5f, 0.0f, (float)(n - 1));
    const int x0 = n > 1 ? min((int)floor(xs), n - 2) : 0;
    const int y0 = n > 1 ? min((int)floor(ys), n - 2) : 0;
    const float fx = xs - (float)x0, fy = ys - (float)y0;
    for (int c = 0; c < nch; ++c) {
        const float top = fetch(src, x0, y0, n, nch, c) * (1.0f - fx) + fetch(src, x0 + 1, y0, n, nch, c) * fx;
        const float bot = fetch(src, x0, y0 + 1, n, nch, c) * (1.0f - fx) + fetch(src, x0 + 1, y0 + 1, n, nch, c) * fx;
        out[c] = top * (1.0f - fy) + bot * fy;
    }
}

__kernel void vignette(__global const float *src, __global float *dst, __constant float *coeffs, const int n,
                       const int nch, const float xc, const float yc, const float radius)
{
    const int gid = get_global_id(0);
    if (gid >= n * n)
        return;
    const int i = gid / n;
    const int j = gid - i * n;
    const float r = hypot((float)j - xc, (float)(n - 1 - i) - yc) / radius;
    float den = 0.0f;
    for (int k = 8; k >= 0; --k)
        den = den * r + coeffs[k];
    const float f = 1.0f / den;
    for (int c = 0; c < nch; ++c)
        dst[(size_t)gid * nch + c] = src[(size_t)gid * nch + c] * f;
}
