/*
 * tonemap.cl -- global tone-mapping operators, per pixel, to sRGB-encoded codes.
 * NumPy twin: hdrcl.report.tonemap.apply_global (float64); the operators and their
 * scene statistics (scale, white) are defined there.
 *
 * Per pixel: NaN, infinite and negative values count as 0; Lw = Rec.709 luminance
 * (the channel itself when nch == 1); then
 *   op 0 reinhard  L = scale Lw, Ld = L (1 + L / white^2) / (1 + L), out = RGB Ld / Lw
 *   op 1 drago     L = scale Lw, Ld = ln(1 + L) / (log10(white + 1) ln(2 + 8 (L / white)^p)),
 *                  p = ln(0.85) / ln(0.5), out = RGB Ld / Lw
 *   op 2 filmic    per channel x = scale RGB, out = h(2 x) / h(11.2), Hable's curve h
 * out is clamped to [0, 1], sRGB-encoded and rounded half up to [0, outmax].
 *
 * Build options
 *   -DOUT_T=uchar|ushort   output integer type (default uchar)
 *
 * Arguments (units, layout)
 *   radiance  float [npix * nch]   linear Rec.709 radiance, channels interleaved
 *   out       OUT_T [npix * nch]   sRGB codes, same layout
 *   npix, nch                      pixels in this strip; 1 or 3 channels
 *   op                             0 reinhard, 1 drago, 2 filmic
 *   scale, white                   from the statistics (white unused by filmic)
 *   outmax                         2^bits - 1
 */
#ifndef OUT_T
#define OUT_T uchar
#endif

static float clean(const float v)
{
    return (isfinite(v) && v > 0.0f) ? v : 0.0f;
}

static float hable(const float x)
{
    const float A = 0.22f, B = 0.30f, C = 0.10f, D = 0.20f, E = 0.01f, F = 0.30f;
    return (x * (A * x + C * B) + D * E) / (x * (A * x + B) + D * F) - E / F;
}

static OUT_T encode(const float linear, const float outmax)
{
    const float v = clamp(linear, 0.0f, 1.0f);
    const float s = v <= 0.0031308f ? 12.92f * v : 1.055f * pow(v, 1.0f / 2.4f) - 0.055f;
    return (OUT_T)clamp(floor(s * outmax + 0.5f), 0.0f, outmax);
}

__kernel void tonemap_global(__global const float *radiance,
                             __global OUT_T *out,
                             const int npix,
                             const int nch,
                             const int op,
                             const float scale,
                             const float white,
                             const float outmax)
{
    const int i = get_global_id(0);
    if (i >= npix)
        return;
    const size_t base = (size_t)i * nch;
    float rgb[3];
    for (int c = 0; c < nch; c++)
        rgb[c] = clean(radiance[base + c]);
    if (op == 2) {
        const float norm = 1.0f / hable(11.2f);
        for (int c = 0; c < nch; c++)
            out[base + c] = encode(hable(2.0f * scale * rgb[c]) * norm, outmax);
        return;
    }
    const float lw = nch == 1 ? rgb[0] : 0.2126f * rgb[0] + 0.7152f * rgb[1] + 0.0722f * rgb[2];
    const float l = scale * lw;
    float ld;
    if (op == 0) {
        ld = l * (1.0f + l / (white * white)) / (1.0f + l);
    } else {
        const float p = log(0.85f) / log(0.5f);
        ld = log1p(l) / (log10(white + 1.0f) * log(2.0f + 8.0f * pow(l / white, p)));
    }
    const float ratio = lw > 0.0f ? ld / lw : 0.0f;
    for (int c = 0; c < nch; c++)
        out[base + c] = encode(rgb[c] * ratio, outmax);
}
