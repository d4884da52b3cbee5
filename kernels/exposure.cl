/*
 * exposure.cl -- virtual photograph from a radiance map: Z = g^-1(ln E + ln dt).
 * NumPy twin: hdrcl.reference.expose.
 *
 * g is given non-decreasing (running maximum of the response) and inverted by binary
 * search plus linear interpolation between code values: with x = ln E + ln dt and k
 * the largest code with g(k) <= x, z = k + (x - g(k)) / (g(k+1) - g(k)). E <= 0, NaN
 * and x < g(0) give 0; x >= g(L-1) and +inf give L-1. The code is rescaled to the output
 * depth and rounded half up: out = floor(z * scale + 0.5), clamped to [0, outmax].
 *
 * Build options
 *   -DOUT_T=uchar|ushort   output integer type (default uchar)
 *
 * Arguments (units, layout)
 *   radiance  float [nvals]   linear relative radiance, channels interleaved (i*nch + c)
 *   gtab      float [C][L]    non-decreasing g_c(z), natural-log exposure units
 *   out       OUT_T [nvals]   codes
 *   nvals                     values in this strip (pixels * nch)
 *   nch, levels               C, L
 *   log_t                     ln dt of the virtual exposure (seconds)
 *   scale                     (2^out_bits - 1) / (L - 1)
 *   outmax                    2^out_bits - 1
 */
#ifndef OUT_T
#define OUT_T uchar
#endif

__kernel void expose(__global const float *radiance,
                     __global const float *gtab,
                     __global OUT_T *out,
                     const int nvals,
                     const int nch,
                     const int levels,
                     const float log_t,
                     const float scale,
                     const float outmax)
{
    const int i = get_global_id(0);
    if (i >= nvals)
        return;
    const int c = i % nch;
    const float e = radiance[i];
    __global const float *g = gtab + (size_t)c * levels;
    float z;
    if (!(e > 0.0f)) {
        z = 0.0f;
    } else if (isinf(e)) {
        z = (float)(levels - 1);
    } else {
        const float x = log(e) + log_t;
        if (x < g[0]) {
            z = 0.0f;
        } else if (x >= g[levels - 1]) {
            z = (float)(levels - 1);
        } else {
            int a = 0;
            int b = levels - 1; /* invariant: g[a] <= x < g[b] */
            while (b - a > 1) {
                const int m = (a + b) >> 1;
                if (g[m] <= x)
                    a = m;
                else
                    b = m;
            }
            z = (float)a + (x - g[a]) / (g[b] - g[a]);
        }
    }
    const float v = clamp(floor(z * scale + 0.5f), 0.0f, outmax);
    out[i] = (OUT_T)v;
}
