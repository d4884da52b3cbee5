/*
 * fusion.cl -- per-pixel fusion of a bracket into a radiance map
 * (Debevec & Malik 1997, eq. 6). NumPy twin: hdrcl.core.reference.fuse.
 *
 *   ln E = sum_j w(Z_j) (g_c(Z_j) - ln dt_j) / sum_j w(Z_j)
 *
 * over the evidence frames of each value (pixel-channel). Frames are ordered by
 * increasing exposure. Walking them from the shortest: a valid sample at or above ZHI
 * (clipped) ends the evidence -- it and every longer frame prove only a lower bound; a
 * valid sample at or below ZLO (noise floor) discards the evidence gathered so far --
 * it and every shorter frame prove only an upper bound. What remains is the frames
 * strictly between the longest black and the shortest clipped sample.
 *
 * In a consistent bracket a value's black samples all come before its in-range ones
 * and its clipped ones after: the evidence is then every in-range sample, which the
 * fast path sums with no per-sample test. Besides the weighted sums it sums a pattern
 * term that says which frames were clipped and which black -- their bits (up to 12
 * frames), or their counts and index sums (up to 16) -- and one test per value at the
 * end (settle) says whether they are the longest and the shortest ones. Values that
 * fail it (moving or flickering subjects, misregistered edges) go to fuse_fix, which
 * walks their frames.
 *
 * Three kernels share one strip of codes:
 *
 *   fuse      the fast path. Each work item takes 4 pixels (4*NCH consecutive values,
 *             so every value's channel is known at compile time) and makes one
 *             16-byte load per sample from a table per channel (lut below), multiplied
 *             by a factor per frame and added to the value's private float4: one
 *             multiply and one add per sample (written as such: with fma() the
 *             kernel ran 3 times slower on the PyPI PoCL, measured). One division,
 *             one exp2 (exp2_fast) and the order test per value, none per sample. A
 *             value whose in-range samples weigh nothing, or whose clipped or black
 *             samples are out of order, is written as -1 (impossible radiance), and its
 *             work item puts its 4 pixels on fuse_fix's list (todo; counts[3] its
 *             length: one atomic add per such work item, none on the fast path). With
 *             more than 16 frames (or no -DNFRAMES) it walks the rule per sample
 *             instead (a gate and a reset per value; about twice as slow).
 *   fuse_tail the last npix % 4 pixels, one value at a time, walking the frames (a
 *             pixel with a value to fix goes on the list).
 *   fuse_fix  run only when the list is not empty: one work item per listed pixel
 *             walks the frames of its flagged values (the evidence as defined above),
 *             applies the twin's bound rules to those whose evidence weighs nothing, then the
 *             hue rule across the pixel's channels, and writes the pixel's clip mask:
 *               clipped high (the shortest valid frame reads >= ZHI): the lower bound
 *                 ghi_c(Z) - ln dt_shortest (ghi: running maximum of g); clipped_high
 *               else black (the longest valid frame reads <= ZLO): the upper bound
 *                 glo_c(Z) - ln dt_longest (glo: running minimum of g from the top);
 *                 clipped_low
 *               else (frames contradict each other): the weighted mean over every valid
 *                 frame reading inside (ZLO, ZHI); none: the first bound if the
 *                 shortest valid frame reads 2Z >= L, else the second; not counted
 *               valid in no frame: 0; no_data
 *             Hue: a channel clipped high takes the largest value among the pixel's
 *             measured and clipped-high channels; clipped low, the smallest among the
 *             measured and clipped-low ones.
 *
 * Where the time goes (12 MP x 7 frames, CPU seconds of a whole bracket on a 2-core Xeon,
 * scripts/fusion_bench.py): Intel's runtime about 0.13 s in fuse, of which the samples'
 * sums about 0.09 (three instructions per sample: the code's load, the index, a multiply-
 * add from the table) and exp2_fast, the division and the order test the rest; about
 * 0.03 s more per bracket in launching and waiting on ~50 strips and fuse_fix. Tried and
 * slower there: one value per work item, vectorised across work items (the table reads
 * become gathers, ~20 cycles per 16), settle on 16-wide vectors, 8 or 32 pixels per work
 * item, the fixes inlined into fuse (3x slower: the fast loop lost its registers), no
 * FP contraction. PoCL: about 0.19 s in fuse.
 *
 * Build options
 *   -DPIXEL_T=uchar|ushort  integer type of the codes (default uchar)
 *   -DNCH=1|3               channels per pixel (default 3)
 *   -DHAS_VALID             per-frame validity masks are given
 *   -DLEVELS=256|65536      code values (must equal the levels argument)
 *   -DZLO, -DZHI            noise floor and clip codes, hdrcl.core.weights.clip_levels
 *                           (8-bit 5 and 250, 16-bit 1285 and 64250)
 *   -DNFRAMES=P             optional: frame count fixed at build time (must equal the
 *                           nframes argument): the compiler then unrolls the frame loop,
 *                           and up to 16 frames each frame is its own argument
 *
 * Arguments (units, layout)
 *   f0..f15  PIXEL_T [npix*NCH]  with -DNFRAMES up to 16: frame p's codes of the strip
 *   foff     int16               from element foff.s<p> of f<p> (the host passes the
 *                                decoder's memory in place, from an aligned address at
 *                                or before the strip); pixels row-major, channels
 *                                interleaved (i*NCH + c); unused f<p>: any buffer
 *   frames   PIXEL_T [P][plane]  otherwise: all frames in one buffer, frame p from
 *   plane                        p*plane
 *   valid    uchar [P][vplane]   1 where frame p measures pixel i (HAS_VALID only)
 *   lut      float4 [NCH][L]     (w(z) g_c(z) / ln 2, w(z), w(z), [z >= ZHI] + K [z <= ZLO]),
 *                                w = 0 outside (ZLO, ZHI), K = 2^P up to 12 frames, else
 *                                B: a sample of frame p adds lut * (1, 1, -ln dt_p / ln 2,
 *                                2^p or A + p), so .x + .z is the weighted log2 exposure,
 *                                .y the weight, .w the pattern
 *   lt2      float [P]           ln dt_p / ln 2
 *   ghi, glo float [NCH][L]      running maximum (from code 0) and running minimum (from
 *                                the top code) of g_c / ln 2: log2 exposure units
 *   out      float [npix*NCH]    linear relative radiance E, channels interleaved
 *   counts   uint [4]            clipped high, black, valid nowhere (counts); [3] the
 *                                length of todo, cleared by the host
 *   todo     int [npix]          pixels fuse_fix walks (in no particular order)
 *   mask     uchar [npix]        fuse_fix: for each listed pixel, 1 some channel clipped
 *                                high, 2 some channel clipped low (or'ed), 0 otherwise
 *                                (the host clears the rest)
 *   npix                         pixels in this strip
 *   nfix                         fuse_fix: the length of todo
 *   nframes, levels              P, L
 *   vplane                       elements between frames in `valid`
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
/* Noise floor and clip codes: the host passes hdrcl.core.weights.clip_levels; these
 * defaults, the same for 8 and 16 bits, serve builds without options (device probes). */
#ifndef ZHI
#define ZHI ((250 * (LEVELS - 1) + 127) / 255)
#endif
#ifndef ZLO
#define ZLO (LEVELS - 1 - ZHI)
#endif

/* The pattern term (see the top). Up to 12 frames: frame p's bit 2^p for a clipped
 * sample, 2^(P + p) for a black one (PAT_POW2; 2P bits, exact below 2^24). Up to 16:
 * A + p and B (A + p), A above any index sum (120), B above any A n + s (2168), so
 * B (A n + s) + A n + s stays below 2^24. */
#define PAT_A 128.0f
#define PAT_B 4096.0f

/* Where frame p's codes are. Up to MAX_FRAME_ARGS frames (with -DNFRAMES) each frame is
 * its own buffer argument, f0 .. f15, plus an element offset per frame (foff): the host passes
 * the decoder's own memory in place (no copy into a device buffer). Beyond that, or
 * without -DNFRAMES, the frames are packed in one buffer, frame p at p * plane. */
#define MAX_FRAME_ARGS 16
/* FRAME(p) picks the argument by a chain of selects, which folds to one pointer where p is
 * known at compile time; every loop over frames has p the same in all work items (Intel's
 * CPU runtime crashed on fuse_fix when the pointers sat in a private array indexed per
 * work item). */
#if defined(NFRAMES) && NFRAMES <= MAX_FRAME_ARGS
#define FP __global const PIXEL_T *
#define FRAMES_PARAM FP f0, FP f1, FP f2, FP f3, FP f4, FP f5, FP f6, FP f7, FP f8, FP f9, \
    FP f10, FP f11, FP f12, FP f13, FP f14, FP f15, const int16 foff
#define FRAME(p) ((p) == 0 ? f0 + foff.s0 : (p) == 1 ? f1 + foff.s1 : (p) == 2 ? f2 + foff.s2 : \
    (p) == 3 ? f3 + foff.s3 : (p) == 4 ? f4 + foff.s4 : (p) == 5 ? f5 + foff.s5 : (p) == 6 ? f6 + foff.s6 : \
    (p) == 7 ? f7 + foff.s7 : (p) == 8 ? f8 + foff.s8 : (p) == 9 ? f9 + foff.s9 : (p) == 10 ? f10 + foff.sa : \
    (p) == 11 ? f11 + foff.sb : (p) == 12 ? f12 + foff.sc : (p) == 13 ? f13 + foff.sd : (p) == 14 ? f14 + foff.se : \
    f15 + foff.sf)
#define FRAMES_PASS f0, f1, f2, f3, f4, f5, f6, f7, f8, f9, f10, f11, f12, f13, f14, f15, foff
#define FRAMES_DECL FRAMES_PARAM
#else
#define FRAMES_PARAM __global const PIXEL_T *frames, const int plane
#define FRAME(p) (frames + (size_t)(p) * plane)
#define FRAMES_PASS frames, plane
#define FRAMES_DECL __global const PIXEL_T *frames, const int plane
#endif

/* Frame count: a compile-time constant when the host gives -DNFRAMES (the frame loop
 * then unrolls), else the nframes argument. */
#ifdef NFRAMES
#define FRAME_COUNT NFRAMES
#if NFRAMES <= 16
#define PATTERNS
#endif
#if NFRAMES <= 12
#define PAT_POW2
#define PAT_SCALE ((float)(1 << NFRAMES))
#endif
#else
#define FRAME_COUNT nframes
#endif

/* The evidence of one value, walking its frames from the shortest: (weighted log2
 * exposure, weight) of the in-range samples after the last black one and before the
 * first clipped one (the twin's rule, exactly). */
inline float2 evidence(FRAMES_DECL, __global const uchar *valid, __global const float4 *lut,
                       __global const float *lt2, const int i, const int c, const int nframes,
                       const int levels, const int vplane)
{
    float4 a = (float4)(0.0f);
    int stop = 0;
    for (int p = 0; p < nframes; ++p) {
#ifdef HAS_VALID
        if (!valid[(size_t)p * vplane + i])
            continue;
#endif
        const int z = FRAME(p)[(size_t)i * NCH + c];
        stop |= z >= ZHI;
        if (z <= ZLO)
            a = (float4)(0.0f);
        else if (!stop)
            a += lut[c * levels + z] * (float4)(1.0f, 1.0f, -lt2[p], 0.0f);
    }
    return (float2)(a.x + a.z, a.y);
}

/* Value k of a work item's 4 pixels (channel k % NCH, pixel k / NCH, both constants)
 * adds its sample of frame p, scaled by the frame's factor s, to its accumulator a<k>;
 * a masked-out sample adds 0. Without PATTERNS each value also keeps a gate g<k> (0 once
 * a clipped sample was seen) and a black sample resets the sum: the walk, per sample. */
#ifdef PATTERNS
#ifdef HAS_VALID
#define SAMPLE(k) a##k += l[((k) % NCH) * LEVELS + f[k]] * (m[(k) / NCH] ? s : (float4)(0.0f))
#else
#define SAMPLE(k) a##k += l[((k) % NCH) * LEVELS + f[k]] * s
#endif
#else
#ifdef HAS_VALID
#define SAMPLE(k) { const int z_ = m[(k) / NCH] ? (int)f[k] : (ZLO + 1); \
    g##k = z_ >= ZHI ? 0.0f : g##k; \
    a##k = z_ <= ZLO ? (float4)(0.0f) \
                     : a##k + l[((k) % NCH) * LEVELS + z_] * (m[(k) / NCH] ? g##k * s : (float4)(0.0f)); }
#else
#define SAMPLE(k) { const int z_ = f[k]; \
    g##k = z_ >= ZHI ? 0.0f : g##k; \
    a##k = z_ <= ZLO ? (float4)(0.0f) : a##k + l[((k) % NCH) * LEVELS + z_] * (g##k * s); }
#endif
#endif


/* 2^x for the fast path, within about 2 float32 ulps: the integer n nearest x by the
 * rounding of x + 1.5 * 2^23, 2^n by the exponent bits (in two factors, so that every x
 * in [-252, 252] is as exact as exp2's), 2^f for f = x - n in [-1/2, 1/2] by its Taylor
 * polynomial of degree 7 (truncation below 6e-9). Plain arithmetic on 4 lanes: the
 * library's exp2 cost about 40 % of the fast path on Intel's CPU runtime (3 calls per work
 * item); this one, a fifth of that. */
inline float4 exp2_fast(float4 x)
{
    x = clamp(x, -252.0f, 252.0f);
    const float4 big = x + 12582912.0f;
    const float4 n = big - 12582912.0f;
    const float4 f = x - n;
    float4 p = 1.5252733804059840e-05f; /* ln(2)^k / k!, k = 7 .. 0 */
    p = p * f + 1.5403530393381606e-04f;
    p = p * f + 1.3333558146428443e-03f;
    p = p * f + 9.6181291076284772e-03f;
    p = p * f + 5.5504108664821580e-02f;
    p = p * f + 2.4022650695910071e-01f;
    p = p * f + 6.9314718055994531e-01f;
    p = p * f + 1.0f;
    const int4 ni = as_int4(big) - 0x4b400000; /* n, from the low mantissa bits */
    const int4 n1 = ni >> 1;
    return p * as_float4((n1 + 127) << 23) * as_float4((ni - n1 + 127) << 23);
}

/* Four values' radiance from their sums a, b, c, d: exp2(num / den) where the sum is
 * their evidence -- it weighs something, and the pattern term says the clipped frames
 * are the longest ones and the black frames the shortest -- else -1, and *bad set.
 * Every step is exact float arithmetic on integers below 2^24. An invalid frame inside
 * a clipped or black run fails the test: the value goes to fuse_fix needlessly but
 * harmlessly (it walks the valid frames). */
inline float4 settle(const float4 a, const float4 b, const float4 c, const float4 d, int *bad)
{
    const float4 num = (float4)(a.x + a.z, b.x + b.z, c.x + c.z, d.x + d.z);
    const float4 den = (float4)(a.y, b.y, c.y, d.y);
#if !defined(PATTERNS)
    const int4 order = (int4)(-1); /* the per-sample walk needs no test */
#elif defined(PAT_POW2)
    const float4 pat = (float4)(a.w, b.w, c.w, d.w);
    /* pat = H + 2^P L, H and L the bit patterns of the clipped and black frames: in
     * order when 2^P - H (H the top bits) and L + 1 (L the bottom bits) are powers of
     * two, which have no mantissa bits. */
    const float4 low = floor(pat * (1.0f / PAT_SCALE));
    const float4 h = PAT_SCALE - (pat - PAT_SCALE * low);
    const int4 order = ((as_int4(h) | as_int4(low + 1.0f)) & 0x7fffff) == 0;
#else
    /* pat = A n_h + s_h + B (A n_l + s_l), n the counts and s the index sums: in order
     * when s_h is the largest sum n_h indices can have and s_l the smallest. */
    const float4 pat = (float4)(a.w, b.w, c.w, d.w);
    const float4 low = floor(pat * (1.0f / PAT_B));
    const float4 high = pat - PAT_B * low;
    const float4 nh = floor(high * (1.0f / PAT_A)), sh = high - PAT_A * nh;
    const float4 nl = floor(low * (1.0f / PAT_A)), sl = low - PAT_A * nl;
    const int4 order = (2.0f * sh == nh * ((float)(2 * FRAME_COUNT - 1) - nh))
                       & (2.0f * sl == nl * (nl - 1.0f));
#endif
    const int4 ok = (den > 0.0f) & order;
    *bad |= any(ok == 0);
    return select((float4)(-1.0f), exp2_fast(num / den), ok);
}

/* The fast path. Per sample: one scalar load of the code, one 16-byte load from the
 * channel's table (its index is the code plus a constant) and one multiply and add into
 * that value's own accumulator -- no test: clipping is settled once per value at the
 * end (a per-sample test made this kernel 2-3 times slower on CPU drivers). Scalar
 * loads and private accumulators, rather than vector loads and lane shuffles, keep the
 * inner loop at a few instructions per sample on CPU drivers; the table is per channel,
 * not per frame (12 KB at 8 bits: it stays in the L1 cache); summation order is that of
 * the frames, as in the twin. A work item with a value to fix marks its 4 pixels in
 * `todo` for fuse_fix. */
__kernel void fuse(FRAMES_PARAM,
                   __global const uchar *valid,
                   __global const float4 *lut,
                   __global const float *lt2,
                   __global float *out,
                   __global uint *counts,
                   __global int *todo,
                   const int npix,
                   const int nframes,
                   const int levels,
                   const int vplane)
{
    const int q = get_global_id(0);
    const int i0 = q * 4; /* first pixel of this work item */
    if (i0 + 4 > npix) /* the last npix % 4 pixels are fuse_tail's */
        return;
    const size_t v0 = (size_t)i0 * NCH;
    __global float *o = out + v0;
    float4 a0 = 0.0f, a1 = 0.0f, a2 = 0.0f, a3 = 0.0f;
#if NCH == 3
    float4 a4 = 0.0f, a5 = 0.0f, a6 = 0.0f, a7 = 0.0f, a8 = 0.0f, a9 = 0.0f, a10 = 0.0f, a11 = 0.0f;
#endif
#ifndef PATTERNS
    float g0 = 1.0f, g1 = 1.0f, g2 = 1.0f, g3 = 1.0f;
#if NCH == 3
    float g4 = 1.0f, g5 = 1.0f, g6 = 1.0f, g7 = 1.0f, g8 = 1.0f, g9 = 1.0f, g10 = 1.0f, g11 = 1.0f;
#endif
#endif
    __global const float4 *l = lut;
    for (int p = 0; p < FRAME_COUNT; ++p) {
        __global const PIXEL_T *f = FRAME(p) + v0;
#if defined(PAT_POW2)
        const float4 s = (float4)(1.0f, 1.0f, -lt2[p], (float)(1 << p));
#elif defined(PATTERNS)
        const float4 s = (float4)(1.0f, 1.0f, -lt2[p], PAT_A + (float)p);
#else
        const float4 s = (float4)(1.0f, 1.0f, -lt2[p], 0.0f);
#endif
#ifdef HAS_VALID
        __global const uchar *m = valid + (size_t)p * vplane + i0;
#endif
        SAMPLE(0); SAMPLE(1); SAMPLE(2); SAMPLE(3);
#if NCH == 3
        SAMPLE(4); SAMPLE(5); SAMPLE(6); SAMPLE(7); SAMPLE(8); SAMPLE(9); SAMPLE(10); SAMPLE(11);
#endif
    }
    /* One flag store per work item at most. */
    int bad = 0;
    vstore4(settle(a0, a1, a2, a3, &bad), 0, o);
#if NCH == 3
    vstore4(settle(a4, a5, a6, a7, &bad), 1, o);
    vstore4(settle(a8, a9, a10, a11, &bad), 2, o);
#endif
    if (bad) { /* the 4 pixels go on fuse_fix's list (rarely: no cost on the fast path) */
        const uint k = atomic_add(&counts[3], 4u);
        vstore4((int4)(i0, i0 + 1, i0 + 2, i0 + 3), 0, todo + k);
    }
}

/* The last npix % 4 pixels of a strip (fuse takes whole groups of 4): one work item per
 * pixel from `first`. A separate kernel keeps the ragged end's loops out of fuse, where
 * they stop some drivers from vectorising across work items. */
__kernel void fuse_tail(FRAMES_PARAM,
                        __global const uchar *valid,
                        __global const float4 *lut,
                        __global const float *lt2,
                        __global float *out,
                        __global uint *counts,
                        __global int *todo,
                        const int npix,
                        const int nframes,
                        const int levels,
                        const int vplane,
                        const int first)
{
    const int i = first + (int)get_global_id(0);
    if (i >= npix)
        return;
    int bad = 0;
    for (int c = 0; c < NCH; ++c) {
        const float2 a = evidence(FRAMES_PASS, valid, lut, lt2, i, c, nframes, levels, vplane);
        bad |= !(a.y > 0.0f);
        out[(size_t)i * NCH + c] = a.y > 0.0f ? exp2(a.x / a.y) : -1.0f;
    }
    if (bad)
        todo[atomic_inc(&counts[3])] = i;
}

/* The pixels on fuse's and fuse_tail's list (`todo`, nfix of them: counts[3]). */
__kernel void fuse_fix(FRAMES_PARAM,
                       __global const uchar *valid,
                       __global const float4 *lut,
                       __global const float *lt2,
                       __global const float *ghi,
                       __global const float *glo,
                       __global float *out,
                       __global uint *counts,
                       __global const int *todo,
                       __global uchar *mask,
                       const int nfix,
                       const int nframes,
                       const int levels,
                       const int vplane)
{
    const int k = get_global_id(0);
    if (k >= nfix)
        return;
    const int i = todo[k];
    int first = -1, last = -1;
    for (int p = 0; p < nframes; ++p) {
#ifdef HAS_VALID
        if (!valid[(size_t)p * vplane + i])
            continue;
#endif
        if (first < 0)
            first = p;
        last = p;
    }
    float e[NCH];
    int kind[NCH]; /* 0 measured, 1 clipped high, 2 clipped low, 3 other */
    for (int c = 0; c < NCH; ++c) {
        const size_t v = (size_t)i * NCH + c;
        e[c] = out[v];
        kind[c] = 0;
        if (e[c] >= 0.0f)
            continue;
        const float2 ev = evidence(FRAMES_PASS, valid, lut, lt2, i, c, nframes, levels, vplane);
        if (ev.y > 0.0f) { /* out of order, but measured */
            e[c] = exp2(ev.x / ev.y);
            continue;
        }
        kind[c] = 3;
        if (first < 0) {
            e[c] = 0.0f;
            atomic_inc(&counts[2]);
            continue;
        }
        int zf = 0, zl = 0; /* the codes of the shortest and longest valid frames */
        for (int p = 0; p < nframes; ++p) { /* p the same in every work item: no gather of pointers */
            const int z = FRAME(p)[v];
            zf = p == first ? z : zf;
            zl = p == last ? z : zl;
        }
        if (zf >= ZHI) {
            kind[c] = 1;
            atomic_inc(&counts[0]);
        } else if (zl <= ZLO) {
            kind[c] = 2;
            atomic_inc(&counts[1]);
        } else {
            /* Frames that contradict each other: every valid frame's evidence. */
            float4 a = (float4)(0.0f);
            for (int p = 0; p < nframes; ++p) {
#ifdef HAS_VALID
                if (!valid[(size_t)p * vplane + i])
                    continue;
#endif
                a += lut[c * levels + FRAME(p)[v]] * (float4)(1.0f, 1.0f, -lt2[p], 0.0f);
            }
            if (a.y > 0.0f) {
                e[c] = exp2((a.x + a.z) / a.y);
                continue;
            }
        }
        if (kind[c] == 1 || (kind[c] == 3 && 2 * zf >= levels))
            e[c] = exp2(ghi[c * levels + zf] - lt2[first]);
        else
            e[c] = exp2(glo[c * levels + zl] - lt2[last]);
    }
    /* Hue: a clipped channel is not darker (high) or brighter (low) than the pixel's
     * measured channels and those clipped the same way. */
    float top = -INFINITY, bottom = INFINITY;
    for (int c = 0; c < NCH; ++c) {
        if (kind[c] == 0 || kind[c] == 1)
            top = fmax(top, e[c]);
        if (kind[c] == 0 || kind[c] == 2)
            bottom = fmin(bottom, e[c]);
    }
    uchar flags = 0;
    for (int c = 0; c < NCH; ++c) {
        if (kind[c] == 1) {
            e[c] = top;
            flags |= 1;
        } else if (kind[c] == 2) {
            e[c] = bottom;
            flags |= 2;
        }
        out[(size_t)i * NCH + c] = e[c];
    }
    mask[i] = flags;
}

/* ---- Deghosting: the departures (hdrcl.core.deghost.departures is the twin) ----------
 * One work item per pixel of a strip (with its context rows): 1 in `raw` where some
 * frame p and channel c, with fused > 0 and a code z in zlo..zhi (valid), give
 *     x = tab[c][z] - lt[p] - bias[p][c][b]
 * outside the fused value's 3x3 envelope of ln (edges repeated) by more than
 * tol[p][c][b]; b, the bin of the code the fused value predicts, counts the `edges`
 * (the curve one code below each bin's first code) under ln fused + lt[p].
 *   frames  P planes of rows x width x NCH codes, `plane` elements apart
 *   valid   P planes of rows x width (1 = valid) when has_valid, else unread
 *   fused   rows x width x NCH float32 radiance (before replacement)
 *   tab     NCH x LEVELS g (ln); lt P ln dt; edges NCH x (BINS - 1) ln
 *   bias, tol  P x NCH x BINS ln
 *   screen  P x NCH x 2: the smallest and largest bias over the bins (ln)
 *   raw     rows x width uchar out */
#ifndef BINS
#define BINS 16
#endif
#ifndef FLOOR
#define FLOOR 0.25f
#endif
__kernel void ghost_raw(__global const PIXEL_T *frames, const int plane, __global const uchar *valid,
                        const int has_valid, __global const float *fused, __global const float *tab,
                        __global const float *lt, __global const float *edges, __global const float *bias,
                        __global const float *tol, __global const float *screen, __global uchar *raw, const int rows, const int width,
                        const int nframes, const int zlo, const int zhi)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= width || y >= rows)
        return;
    const int i = y * width + x;
    float lnf[NCH], lo[NCH], hi[NCH];
    for (int c = 0; c < NCH; c++) {
        lo[c] = fused[i * NCH + c];
        hi[c] = lo[c];
    }
    /* the envelope of the values, then its logarithm (log is increasing): 3 logs a channel */
    for (int dy = -1; dy <= 1; dy++) {
        const int yy = clamp(y + dy, 0, rows - 1);
        for (int dx = -1; dx <= 1; dx++) {
            const int k = (yy * width + clamp(x + dx, 0, width - 1)) * NCH;
            for (int c = 0; c < NCH; c++) {
                lo[c] = fmin(lo[c], fused[k + c]);
                hi[c] = fmax(hi[c], fused[k + c]);
            }
        }
    }
    for (int c = 0; c < NCH; c++) {
        lnf[c] = log(fmax(fused[i * NCH + c], 1e-30f));
        lo[c] = log(fmax(lo[c], 1e-30f));
        hi[c] = log(fmax(hi[c], 1e-30f));
    }
    uchar hit = 0;
    for (int p = 0; p < nframes && !hit; p++) {
        if (has_valid && !valid[(size_t)p * rows * width + i])
            continue;
        for (int c = 0; c < NCH; c++) {
            const int z = frames[(size_t)p * plane + (size_t)i * NCH + c];
            if (z < zlo || z > zhi || !(fused[i * NCH + c] > 0.0f))
                continue;
            const float e = tab[c * LEVELS + z] - lt[p];
            /* screen (as the twin): no bin's bias and tolerance can make it depart */
            if (e - screen[(p * NCH + c) * 2] <= hi[c] + FLOOR && e - screen[(p * NCH + c) * 2 + 1] >= lo[c] - FLOOR)
                continue;
            const float xf = lnf[c] + lt[p];
            __global const float *ed = edges + c * (BINS - 1);
            int b = 0, n = BINS - 1;  /* edges below xf, by bisection (edges non-decreasing) */
            while (n > 0) {
                const int hf = n >> 1;
                if (ed[b + hf] < xf) {
                    b += hf + 1;
                    n -= hf + 1;
                } else {
                    n = hf;
                }
            }
            const int k = (p * NCH + c) * BINS + b;
            const float xv = e - bias[k];
            if (xv > hi[c] + tol[k] || xv < lo[c] - tol[k])
                hit = 1;
        }
    }
    raw[i] = hit;
}
