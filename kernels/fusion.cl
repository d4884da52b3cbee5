/*
 * fusion.cl -- per-pixel fusion of a bracket into a radiance map
 * (Debevec & Malik 1997, eq. 6). NumPy twin: hdrcl.reference.fuse.
 *
 *   ln E = sum_j w(Z_j) (g_c(Z_j) - ln dt_j) / sum_j w(Z_j)
 *
 * One work item per pixel; it loops over channels and frames. Frames are ordered by
 * increasing exposure. A pixel-channel whose weights sum to zero takes the rule of the
 * twin: clipped high (shortest valid frame reads 2Z >= L) -> g_c(Zmax) - ln dt_shortest,
 * otherwise black -> g_c(Zmin) - ln dt_longest; valid in no frame -> 0.
 *
 * Build options
 *   -DPIXEL_T=uchar|ushort   integer type of the codes (default uchar)
 *
 * Arguments (units, layout)
 *   frames   PIXEL_T [P][plane]  codes of a strip: frame p starts at p*plane, pixels
 *                                row-major, channels interleaved (i*nch + c)
 *   valid    uchar [P][vplane]   1 where frame p measures pixel i; read only if has_valid
 *   lut      float [P][C][L]     w(z) * (g_c(z) - ln dt_p), natural-log exposure units
 *   wlut     float [L]           w(z), dimensionless
 *   hi, lo   float [P][C]        g_c(L-1) - ln dt_p and g_c(0) - ln dt_p
 *   out      float [npix*C]      linear relative radiance E, channels interleaved
 *   counts   uint [3]            samples that were clipped high, black, valid nowhere
 *   npix                         pixels in this strip
 *   nframes, nch, levels         P, C, L
 *   plane, vplane                elements between frames in `frames` and `valid`
 */
#ifndef PIXEL_T
#define PIXEL_T uchar
#endif

__kernel void fuse(__global const PIXEL_T *frames,
                   __global const uchar *valid,
                   __global const float *lut,
                   __global const float *wlut,
                   __global const float *hi,
                   __global const float *lo,
                   __global float *out,
                   __global uint *counts,
                   const int npix,
                   const int nframes,
                   const int nch,
                   const int levels,
                   const int plane,
                   const int vplane,
                   const int has_valid)
{
    const int i = get_global_id(0);
    if (i >= npix)
        return;
    for (int c = 0; c < nch; ++c) {
        float num = 0.0f;
        float den = 0.0f;
        int first = -1;
        int last = -1;
        for (int p = 0; p < nframes; ++p) {
            if (has_valid && !valid[(size_t)p * vplane + i])
                continue;
            const int z = frames[(size_t)p * plane + (size_t)i * nch + c];
            num += lut[((size_t)p * nch + c) * levels + z];
            den += wlut[z];
            if (first < 0)
                first = p;
            last = p;
        }
        float e;
        if (den > 0.0f) {
            e = exp(num / den);
        } else if (first < 0) {
            e = 0.0f;
            atomic_inc(&counts[2]);
        } else {
            const int z0 = frames[(size_t)first * plane + (size_t)i * nch + c];
            if (2 * z0 >= levels) {
                e = exp(hi[first * nch + c]);
                atomic_inc(&counts[0]);
            } else {
                e = exp(lo[last * nch + c]);
                atomic_inc(&counts[1]);
            }
        }
        out[(size_t)i * nch + c] = e;
    }
}
