/* Fused CPU kernels that evaluate NBRDF, NeuBRDF's runtime form, the multi-scale gated model, tripleplane and
   NeuMIP (with nbrdf-uv, neumip-frame and neural-appearance's decoder; on a UV texture, NeuPreSS's baselines),
   NeuPreSS's small batches, the dipole BSSRDF, analytic GGX, RGL measured tables,
   SparseBTF and its PCA baseline in one call per batch
   (neumat.nn.cpu_kernels compiles this file at first use; the models say where each applies).

   Rows are processed in blocks of BLOCK, transposed so that each feature's BLOCK values are contiguous: a dense
   layer is then, per group of 4 outputs, 4 x BLOCK accumulators updated by one broadcast weight times one
   contiguous input row, which the compiler vectorises (and keeps in registers) at any SIMD width. Weights come
   packed by neumat.nn.cpu_kernels.PackedMLP: each layer's rows padded with zeros to a multiple of 4, and the next
   layer's columns likewise, so padded outputs never reach a real one. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define BLOCK 64
#define MAX_WIDTH 256

enum { ACT_NONE = 0, ACT_RELU = 1, ACT_LEAKY_RELU = 2, ACT_SILU = 3 };

/* the slope below 0 of an activation: max(v, 0) is v >= 0 ? v : 0 v, leaky ReLU's 0.01 v, none's v (SiLU:
   computed apart) */
static inline float negative_slope(int kind) {
    return kind == ACT_RELU ? 0.f : (kind == ACT_LEAKY_RELU ? 0.01f : 1.f);
}

/* exp and expm1 in float32 without branches (so that they vectorise): x = n ln 2 + r, |r| <= ln 2 / 2, exp(r) by
   its Taylor series to r^8 (relative error < 1e-8 there, below float32's rounding); expm1 of |x| < 1/2 by its own
   series to x^9 (no cancellation), else exp(x) - 1. Inputs clamped to [-87, 88] (exp's float32 range). */
static inline float taylor_expm1(float r) {
    float p = 1.f / 362880.f;
    p = p * r + 1.f / 40320.f; p = p * r + 1.f / 5040.f; p = p * r + 1.f / 720.f; p = p * r + 1.f / 120.f;
    p = p * r + 1.f / 24.f; p = p * r + 1.f / 6.f; p = p * r + 0.5f; p = p * r + 1.f;
    return p * r;
}

static inline float fast_exp(float x) {
    x = x < -87.f ? -87.f : (x > 88.f ? 88.f : x);
    float n = rintf(x * 1.4426950408889634f);
    float r = x - n * 0.693145751953125f - n * 1.428606765330187e-06f;
    int32_t bits = ((int32_t)n + 127) << 23;
    float scale;
    memcpy(&scale, &bits, sizeof scale);
    return (taylor_expm1(r) + 1.f) * scale;
}

static inline float fast_expm1(float x) {
    float small = taylor_expm1(x);
    float large = fast_exp(x) - 1.f;
    return x > -0.5f && x < 0.5f ? small : large;
}

/* atan2 and log in float32 without branches (so that a block's loop vectorises): atan by Cephes' atanf
   (reduction to |x| <= tan(pi / 8), a degree-4 polynomial in x^2; about 1 ulp), log by the exponent's bits and
   log1p of the mantissa in [sqrt(1/2), sqrt(2)) by the series of atanh (relative error < 1e-7) */
static inline float fast_atan(float x) {
    float ax = fabsf(x);
    float base = ax > 2.414213562373095f ? 1.5707963267948966f : (ax > 0.4142135623730950f ? 0.7853981633974483f : 0.f);
    float t = ax > 2.414213562373095f ? -1.f / (ax > 1.f ? ax : 1.f)
              : (ax > 0.4142135623730950f ? (ax - 1.f) / (ax + 1.f) : ax);
    float z = t * t;
    float y = base + ((((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z
                       - 3.33329491539e-1f) * z * t + t);
    return copysignf(y, x);
}

static inline float fast_atan2(float y, float x) {
    float a = fast_atan(y / (x != 0.f ? x : 1.f));
    float off = x < 0.f ? copysignf(3.141592653589793f, y) : 0.f;
    float axis = y != 0.f ? copysignf(1.5707963267948966f, y) : 0.f;
    return x != 0.f ? a + off : axis;
}

static inline float fast_log(float x) {
    int32_t bits;
    memcpy(&bits, &x, sizeof bits);
    int32_t e = ((bits >> 23) & 255) - 127;
    int32_t mbits = (bits & 0x007fffff) | 0x3f800000;
    float m;
    memcpy(&m, &mbits, sizeof m);                /* in [1, 2) */
    int high = m > 1.41421356f;
    m = high ? 0.5f * m : m;
    e += high;
    float f = (m - 1.f) / (m + 1.f), f2 = f * f;  /* log m = 2 atanh f, |f| < 0.172 */
    float p = f2 * (1.f / 9.f) + 1.f / 7.f;
    p = p * f2 + 1.f / 5.f; p = p * f2 + 1.f / 3.f; p = p * f2 + 1.f;
    return 2.f * f * p + (float)e * 0.6931471805599453f;
}

/* sin and cos in float32 of |x| <= pi / 2 without branches: their Taylor series to x^13 and x^14 (truncation below
   6e-8 at pi / 2) */
static inline float fast_sin(float x) {
    float z = x * x, p = -1.f / 6227020800.f;
    p = p * z + 1.f / 39916800.f; p = p * z - 1.f / 362880.f; p = p * z + 1.f / 5040.f; p = p * z - 1.f / 120.f;
    p = p * z + 1.f / 6.f;
    return x - x * z * p;
}

static inline float fast_cos(float x) {
    float z = x * x, p = 1.f / 87178291200.f;
    p = p * z - 1.f / 479001600.f; p = p * z + 1.f / 3628800.f; p = p * z - 1.f / 40320.f; p = p * z + 1.f / 720.f;
    p = p * z - 1.f / 24.f; p = p * z + 0.5f;
    return 1.f - z * p;
}

/* y[o][k] = act(sum_i W[o][i] x[i][k] + b[o]) for o < out, k < BLOCK (W: out x in): 4 outputs at a time, their
   4 x BLOCK sums held in vector registers (GCC / Clang vector extensions, split by the compiler to the machine's
   SIMD width) while the inputs stream past; the last out % 4 one at a time (each a quarter of a group's
   multiply-adds for the same loads). x and y are 64-byte aligned. */
typedef float vec __attribute__((vector_size(64)));
#define VLEN 16
#define NV (BLOCK / VLEN)

static inline __attribute__((always_inline)) void dense_nv(const float *restrict W, const float *restrict b,
                                                           const float *restrict x, float *restrict y, int in,
                                                           int out, int kind, const int nv) {
    const float slope = negative_slope(kind);
    int o = 0;
    for (; o + 4 <= out; o += 4) {
        vec a0[NV], a1[NV], a2[NV], a3[NV];
        for (int v = 0; v < nv; ++v) {
            a0[v] = (vec){} + b[o]; a1[v] = (vec){} + b[o + 1]; a2[v] = (vec){} + b[o + 2]; a3[v] = (vec){} + b[o + 3];
        }
        const float *w0 = W + (long)o * in, *w1 = w0 + in, *w2 = w1 + in, *w3 = w2 + in;
        for (int i = 0; i < in; ++i) {
            const vec *xi = (const vec *)(x + i * BLOCK);
            const float c0 = w0[i], c1 = w1[i], c2 = w2[i], c3 = w3[i];
            for (int v = 0; v < nv; ++v) {
                a0[v] += c0 * xi[v]; a1[v] += c1 * xi[v]; a2[v] += c2 * xi[v]; a3[v] += c3 * xi[v];
            }
        }
        vec *yo = (vec *)(y + o * BLOCK);
        for (int v = 0; v < nv; ++v) {
            yo[v] = a0[v]; yo[NV + v] = a1[v]; yo[2 * NV + v] = a2[v]; yo[3 * NV + v] = a3[v];
        }
        for (int j = 0; j < 4; ++j) {
            float *yf = y + (o + j) * BLOCK;
            if (kind == ACT_SILU)
                for (int k = 0; k < nv * VLEN; ++k) yf[k] = yf[k] / (1.f + fast_exp(-yf[k]));
            else
                for (int k = 0; k < nv * VLEN; ++k) yf[k] = yf[k] >= 0.f ? yf[k] : slope * yf[k];
        }
    }
    for (; o < out; ++o) {
        vec a[NV];
        for (int v = 0; v < nv; ++v) a[v] = (vec){} + b[o];
        const float *w = W + (long)o * in;
        for (int i = 0; i < in; ++i) {
            const vec *xi = (const vec *)(x + i * BLOCK);
            for (int v = 0; v < nv; ++v) a[v] += w[i] * xi[v];
        }
        vec *yo = (vec *)(y + o * BLOCK);
        for (int v = 0; v < nv; ++v) yo[v] = a[v];
        float *yf = y + o * BLOCK;
        if (kind == ACT_SILU)
            for (int k = 0; k < nv * VLEN; ++k) yf[k] = yf[k] / (1.f + fast_exp(-yf[k]));
        else
            for (int k = 0; k < nv * VLEN; ++k) yf[k] = yf[k] >= 0.f ? yf[k] : slope * yf[k];
    }
}

/* dense on a whole block, and on its first VLEN columns only (a call of a few rows: the rest of the block's
   columns are left as they were, and nothing reads them) */
static void dense(const float *restrict W, const float *restrict b, const float *restrict x, float *restrict y,
                  int in, int out, int kind) {
    dense_nv(W, b, x, y, in, out, kind, NV);
}

static void dense_short(const float *restrict W, const float *restrict b, const float *restrict x,
                        float *restrict y, int in, int out, int kind) {
    dense_nv(W, b, x, y, in, out, kind, 1);
}

/* a call's four block buffers (MAX_WIDTH x BLOCK each), on the heap (256 KB: more than some threads' stacks hold);
   NULL when out of memory */
static float *work_buffers(void) {
    return aligned_alloc(64, 4 * sizeof(float) * MAX_WIDTH * BLOCK);
}

/* the MLP on one transposed block of which the first m rows are wanted: x (dims[0] x BLOCK) in buf0; returns the
   buffer holding the output (its first m columns; all BLOCK when m > VLEN). A call of a few rows (a renderer's
   single query) then costs a sixteen-row MLP, not a whole block's (naive-mlp's 64 x 3 layers: 24 -> 6 us) */
static float *mlp_block(float *buf0, float *buf1, int layers, const int *dims, const float *const *W,
                        const float *const *b, int hidden_act, int m) {
    float *x = buf0, *y = buf1;
    for (int l = 0; l < layers; ++l) {
        (m <= VLEN ? dense_short : dense)(W[l], b[l], x, y, dims[l], dims[l + 1],
                                          l < layers - 1 ? hidden_act : ACT_NONE);
        float *t = x; x = y; y = t;
    }
    return x;
}

/* out (m rows of out_dim, row-major) = v (out_dim x BLOCK, by output) where keep[k] > 0, else 0; rows of 3 (every
   model's RGB) in a loop of constant stride that the compiler vectorises with shuffles (one scalar store per value
   was a tenth of NBRDF's kernel) */
static inline void write_rows(const float *v, const float *keep, int m, int out_dim, float *out) {
    if (out_dim == 3) {
        for (int k = 0; k < m; ++k) {
            const int on = keep[k] > 0.f;
            out[3 * k] = on ? v[k] : 0.f;
            out[3 * k + 1] = on ? v[BLOCK + k] : 0.f;
            out[3 * k + 2] = on ? v[2 * BLOCK + k] : 0.f;
        }
        return;
    }
    for (int k = 0; k < m; ++k)
        for (int c = 0; c < out_dim; ++c) out[out_dim * k + c] = keep[k] > 0.f ? v[c * BLOCK + k] : 0.f;
}

/* NBRDF's half and difference vectors of one (wi, wo) (neumat.core.coords.hd_vectors): h = normalize(wi + wo)
   (h[3]), d = wi in the frame (t, b, h), t = (h_z u, -sin theta_h), u = h.xy / sin theta_h ((1, 0) at the pole)
   (d[3]); returns sin theta_h. Inline and branch-free, so that callers' loops over a block vectorise. */
static inline float hd_vectors(float ix, float iy, float iz, float ox, float oy, float oz, float *h, float *d) {
    float hx = ix + ox, hy = iy + oy, hz = iz + oz;
    float norm = sqrtf(hx * hx + hy * hy + hz * hz);
    const float inv = 1.f / (norm > 1e-12f ? norm : 1e-12f);  /* one division, not three (an ulp from torch's) */
    hx *= inv; hy *= inv; hz *= inv;
    float st = sqrtf(hx * hx + hy * hy);
    const float inv_s = 1.f / (st > 1.17549435e-38f ? st : 1.17549435e-38f);
    float ux = st > 0.f ? hx * inv_s : 1.f, uy = st > 0.f ? hy * inv_s : 0.f;
    float tx = hz * ux, ty = hz * uy, tz = -st;
    float bx = hy * tz - hz * ty, by = hz * tx - hx * tz, bz = hx * ty - hy * tx;
    h[0] = hx; h[1] = hy; h[2] = hz;
    d[0] = tx * ix + ty * iy + tz * iz; d[1] = bx * ix + by * iy + bz * iz; d[2] = hx * ix + hy * iy + hz * iz;
    return st;
}

/* NBRDF (Sztrajman et al. 2021) of directions wi, wo (n x 3, float32): h = normalize(wi + wo), d = wi in the
   frame (t, b, h) of neumat.core.coords.hd_vectors; half_theta: h -> (sin theta_h, 0, cos theta_h); fold: d ->
   (-dx, -dy, dz) where dy < 0; the MLP; then max(expm1(y), 0) (exp_minus_one) or exp(y); 0 where wi.z or wo.z
   <= 0. out: n x out_dim. */
int nbrdf_eval(const float *wi, const float *wo, long n, int layers, const int *dims, const float *const *W,
               const float *const *b, int hidden_act, int half_theta, int fold, int exp_minus_one, int out_dim,
               float *out) {
    if (out_dim >= MAX_WIDTH) return 2;  /* res holds the outputs and the horizon flags */
    float *work = work_buffers();
    if (!work) return 1;
    float *buf0 = work, *buf1 = work + MAX_WIDTH * BLOCK, *res = work + 2 * MAX_WIDTH * BLOCK;
    float tail_i[3 * BLOCK], tail_o[3 * BLOCK];
    for (long s = 0; s < n; s += BLOCK) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        const float *restrict pi = wi + 3 * s, *restrict po = wo + 3 * s;
        if (m < BLOCK) {  /* the last rows, padded with zero directions (finite through every step) */
            memset(tail_i, 0, sizeof tail_i); memset(tail_o, 0, sizeof tail_o);
            memcpy(tail_i, pi, 3 * m * sizeof(float)); memcpy(tail_o, po, 3 * m * sizeof(float));
            pi = tail_i; po = tail_o;
        }
        for (int k = 0; k < BLOCK; ++k) {
            float h[3], d[3];
            float st = hd_vectors(pi[3 * k], pi[3 * k + 1], pi[3 * k + 2], po[3 * k], po[3 * k + 1], po[3 * k + 2],
                                  h, d);
            float flip = fold && d[1] < 0.f ? -1.f : 1.f;
            buf0[k] = half_theta ? st : h[0];
            buf0[BLOCK + k] = half_theta ? 0.f : h[1];
            buf0[2 * BLOCK + k] = h[2];
            buf0[3 * BLOCK + k] = flip * d[0]; buf0[4 * BLOCK + k] = flip * d[1]; buf0[5 * BLOCK + k] = d[2];
            res[out_dim * BLOCK + k] = pi[3 * k + 2] > 0.f && po[3 * k + 2] > 0.f ? 1.f : 0.f;  /* above the horizon */
        }
        const float *restrict y = mlp_block(buf0, buf1, layers, dims, W, b, hidden_act, m);
        if (exp_minus_one)
            for (int i = 0; i < out_dim * BLOCK; ++i) {
                float v = fast_expm1(y[i]);
                res[i] = v > 0.f ? v : 0.f;
            }
        else
            for (int i = 0; i < out_dim * BLOCK; ++i) res[i] = fast_exp(y[i]);
        write_rows(res, res + out_dim * BLOCK, m, out_dim, out + out_dim * s);
    }
    free(work);
    return 0;
}

/* distance of v to the nearest integer: how close a truncation below is to flipping */
static inline float to_integer(float v) { return fabsf(v - rintf(v)); }

/* the HEALPix ring pixel of the unit vector (x, y, z) given tt = atan2(y, x) 2 / pi, float32 step by step as
   neumat.nn.healpix.vec2pix_xyz (healpy's loc2pix), and its margin: the least distance to an integer of the values
   it truncates (and of tt, whose wrap and integer part it uses), so that a caller knows when an error in tt could
   move the pixel. Branch-free and returned by value, so that a loop over a block vectorises. */
typedef struct { int32_t pix; float margin; } RingPixel;

static inline RingPixel ring_pixel(float x, float y, float z, float tt, int nside) {
    const float nf = (float)nside, half_n = 0.5f * (float)nside, three_quarter_n = 0.75f * (float)nside;
    const float third = (float)(1.0 / 3.0), two_thirds = (float)(2.0 / 3.0);
    const int32_t ncap_4n2 = 2 * nside * (nside - 1) + 4 * nside * nside, npix = 12 * nside * nside, m4 = 4 * nside;
    float near = to_integer(tt);
    tt = tt < 0.f ? tt + 4.f : tt;       /* torch.remainder(tt, 4) for tt in (-2, 2] */
    tt = tt >= 4.f ? 0.f : tt;
    float za = fabsf(z);
    float temp1 = tt * nf + half_n, temp2 = z * three_quarter_n;
    float lo = temp1 - temp2, hi = temp1 + temp2;
    int32_t jp = (int32_t)lo, jm = (int32_t)hi;
    int32_t e = (jp + jm + 1 - nside) >> 1;  /* in [0, 4 nside] for |z| <= 2 / 3: remainder by 4 nside */
    e = e >= m4 ? e - m4 : (e < 0 ? e + m4 : e);
    int32_t pix_eq = e + 4 * nside * (jp - jm) + ncap_4n2;
    float tp = tt - truncf(tt);
    float sth = sqrtf(x * x + y * y);
    float tmp = sth * nf / sqrtf((za + 1.f) * third);
    float up_ = tp * tmp, down = (1.f - tp) * tmp;
    int32_t cp = (int32_t)up_, cm = (int32_t)down;
    int32_t ir = cp + cm + 1;
    float at = tt * (float)ir;
    int32_t ip = (int32_t)at;
    ip = ip < 4 * ir - 1 ? ip : 4 * ir - 1;
    ip -= 2 * ir;
    int32_t pix_cap = z > 0.f ? ip + 2 * ir * ir : ip - 2 * ir * ir + npix;
    int eq = za <= two_thirds;
    float d_lo = to_integer(lo), d_hi = to_integer(hi), d_up = to_integer(up_), d_down = to_integer(down);
    float d_at = to_integer(at);
    float m_eq = d_lo < d_hi ? d_lo : d_hi;  /* (not fminf: it does not vectorise) */
    float m_cap = d_up < d_down ? d_up : d_down;
    m_cap = m_cap < d_at ? m_cap : d_at;
    float m = eq ? m_eq : m_cap;
    return (RingPixel){eq ? pix_eq : pix_cap, near < m ? near : m};
}

/* HEALPix ring pixels of unit vectors (x, y, z) (BLOCK each), as neumat.nn.healpix.vec2pix_xyz finds them: each
   product and sum rounded on its own (no fused multiply-adds here), atan2 by the vectorised fast_atan2 (within 5e-7
   of atan2f), and every row whose truncated values lie within `slack` of an integer, where that error could move
   the pixel, again with libm's atan2f (about 1 % of rows; atan2f may still differ by an ulp from torch's at a pixel
   edge). Why: with atan2f on every row the loop could not vectorise, and was a third of NeuBRDF's kernel. */
__attribute__((optimize("fp-contract=off"), noinline))
static void ring_pixels(const float *x, const float *y, const float *z, int nside, int exact, int32_t *pix) {
    const float two_over_pi = (float)(2.0 / 3.14159265358979323846);
    /* tt's error times nside, over 30 times; `exact` (tests): every row again with atan2f */
    const float slack = exact ? INFINITY : 1e-3f + 1e-5f * (float)nside;
    float margin[BLOCK];
    for (int k = 0; k < BLOCK; ++k) {
        RingPixel r = ring_pixel(x[k], y[k], z[k], fast_atan2(y[k], x[k]) * two_over_pi, nside);
        pix[k] = r.pix;
        margin[k] = r.margin;
    }
    for (int k = 0; k < BLOCK; ++k)
        if (margin[k] < slack) pix[k] = ring_pixel(x[k], y[k], z[k], atan2f(y[k], x[k]) * two_over_pi, nside).pix;
}

/* NeuBRDF's direction inputs (neumat.methods.neubrdf.model.direction_inputs) of a block's rows s .. s + BLOCK - 1
   (past n, row s again): NBRDF's (h, d) (neumat.core.coords.hd_vectors), with `warp` (h.x, h.y) rescaled to
   length sqrt(theta_h / (pi / 2)); in: 6 x BLOCK. Branch-free (atan2 by fast_atan2), so that it vectorises. */
static void hd_inputs_block(const float *wi, const float *wo, long s, long n, int warp, float *in) {
    for (int k = 0; k < BLOCK; ++k) {
        long r = s + k < n ? s + k : s;
        float h[3], d[3];
        float st = hd_vectors(wi[3 * r], wi[3 * r + 1], wi[3 * r + 2], wo[3 * r], wo[3 * r + 1], wo[3 * r + 2], h, d);
        float radius = sqrtf(fast_atan2(st, h[2]) / 1.5707963267948966f);
        float scale = warp ? (st > 0.f ? radius / (st > 1e-30f ? st : 1e-30f) : 0.f) : 1.f;
        in[k] = h[0] * scale; in[BLOCK + k] = h[1] * scale; in[2 * BLOCK + k] = h[2];
        in[3 * BLOCK + k] = d[0]; in[4 * BLOCK + k] = d[1]; in[5 * BLOCK + k] = d[2];
    }
}

/* the ring pixels of a block's wi and wo (rows s .. s + BLOCK - 1; past n, row s again) and a prefetch of the table rows they will read (the table is far larger than the caches) */
static void block_pixels(const float *wi, const float *wo, long s, long n, int nside, const float *table, int hidden,
                         int32_t *pix_i, int32_t *pix_o) {
    float c[6 * BLOCK];
    const long south = 12L * nside * nside;
    for (int k = 0; k < BLOCK; ++k) {
        long r = s + k < n ? s + k : s;
        for (int j = 0; j < 3; ++j) { c[j * BLOCK + k] = wi[3 * r + j]; c[(3 + j) * BLOCK + k] = wo[3 * r + j]; }
    }
    ring_pixels(c, c + BLOCK, c + 2 * BLOCK, nside, 0, pix_i);
    ring_pixels(c + 3 * BLOCK, c + 4 * BLOCK, c + 5 * BLOCK, nside, 0, pix_o);
    for (int k = 0; k < BLOCK; ++k) {
        const char *ti = (const char *)(table + (long)pix_i[k] * hidden);
        const char *to = (const char *)(table + (south + pix_o[k]) * hidden);
        for (long byte = 0; byte < (long)hidden * 4; byte += 64) {
            __builtin_prefetch(ti + byte);
            __builtin_prefetch(to + byte);
        }
    }
}

/* y (cols x BLOCK) = the transpose of x (BLOCK x cols, row-major): 8 x 8 tiles transposed in vector registers (a
   scalar transpose was two thirds of NeuBRDF's first-layer step), the last cols % 8 columns one by one */
static void transpose_rows(const float *restrict x, int cols, float *restrict y) {
    typedef float v8 __attribute__((vector_size(32), aligned(4)));
    typedef int i8 __attribute__((vector_size(32)));
    const i8 lo = {0, 8, 1, 9, 4, 12, 5, 13}, hi = {2, 10, 3, 11, 6, 14, 7, 15};
    const i8 lo2 = {0, 1, 8, 9, 4, 5, 12, 13}, hi2 = {2, 3, 10, 11, 6, 7, 14, 15};
    const i8 lo4 = {0, 1, 2, 3, 8, 9, 10, 11}, hi4 = {4, 5, 6, 7, 12, 13, 14, 15};
    int c0 = 0;
    for (; c0 + 8 <= cols; c0 += 8)
        for (int k0 = 0; k0 < BLOCK; k0 += 8) {
            v8 r[8], t[8], u[8];
            for (int j = 0; j < 8; ++j) r[j] = *(const v8 *)(x + (long)(k0 + j) * cols + c0);
            for (int j = 0; j < 8; j += 2) {
                t[j] = __builtin_shuffle(r[j], r[j + 1], lo);
                t[j + 1] = __builtin_shuffle(r[j], r[j + 1], hi);
            }
            for (int j = 0; j < 8; j += 4) {
                u[j] = __builtin_shuffle(t[j], t[j + 2], lo2); u[j + 1] = __builtin_shuffle(t[j], t[j + 2], hi2);
                u[j + 2] = __builtin_shuffle(t[j + 1], t[j + 3], lo2);
                u[j + 3] = __builtin_shuffle(t[j + 1], t[j + 3], hi2);
            }
            for (int j = 0; j < 4; ++j) {  /* u[j]: columns j and j + 4 of rows 0-3; u[j + 4]: of rows 4-7 */
                *(v8 *)(y + (long)(c0 + j) * BLOCK + k0) = __builtin_shuffle(u[j], u[j + 4], lo4);
                *(v8 *)(y + (long)(c0 + j + 4) * BLOCK + k0) = __builtin_shuffle(u[j], u[j + 4], hi4);
            }
        }
    for (; c0 < cols; ++c0)
        for (int k = 0; k < BLOCK; ++k) y[(long)c0 * BLOCK + k] = x[(long)k * cols + c0];
}

/* pre (hidden) += the first layer's direction columns dir_w (6 x hidden) times a row's direction inputs (6, BLOCK
   apart: hd_inputs_block's layout); Config.direction_inputs (h, d), or with warp (h.xy rescaled, h.z, d) */
static inline void add_direction_columns(float *pre, const float *din, const float *dir_w, int hidden) {
    for (int j = 0; j < 6; ++j) {
        const float v = din[j * BLOCK];
        for (int i = 0; i < hidden; ++i) pre[i] += v * dir_w[j * hidden + i];
    }
}

static void store_exp(const float *y, int m, int out_dim, const float *wi, const float *wo, long s, float *out);

/* the rest of NeuBRDF's network after the first layer's sums (res: BLOCK x hidden, row by row): into the MLP's rows,
   activated (first_act), the layers after it, exp; rows s .. s + m - 1 of out, 0 unless wi.z and wo.z > 0 (both
   NeuBRDF kernels) */
static void neubrdf_rest(float *res, int hidden, float *buf0, float *buf1, int first_act, int layers, const int *dims,
                         const float *const *W, const float *const *b, int hidden_act, int out_dim, const float *wi,
                         const float *wo, long s, int m, float *out) {
    const float slope = negative_slope(first_act);
    transpose_rows(res, hidden, buf0);  /* into the MLP's rows, then activated along them */
    if (first_act == ACT_SILU)
        for (int j = 0; j < hidden * BLOCK; ++j) buf0[j] = buf0[j] / (1.f + fast_exp(-buf0[j]));
    else
        for (int j = 0; j < hidden * BLOCK; ++j) buf0[j] = buf0[j] >= 0.f ? buf0[j] : slope * buf0[j];
    store_exp(mlp_block(buf0, buf1, layers, dims, W, b, hidden_act, m), m, out_dim, wi, wo, s, out);
}

/* NeuBRDF's runtime form (Dou, Zheng et al. 2024; neumat.methods.neubrdf.model, uniform corner weights) of
   directions wi, wo (n x 3, float32): the first layer's pre-activations as the sum of the table rows of wi's ring
   pixel and of wo's (offset by 12 nside^2: the S- half), plus with dir_w (6 x hidden: the first layer's columns of
   Config.direction_inputs) those of hd_inputs_block, `first_act`, the MLP's other layers, exp; 0 where wi.z or
   wo.z <= 0. table: (24 nside^2) x hidden. out: n x out_dim. */
int neubrdf_eval(const float *wi, const float *wo, long n, int nside, const float *table, int hidden,
                 const float *dir_w, int dir_warp, int first_act, int layers, const int *dims, const float *const *W,
                 const float *const *b, int hidden_act, int out_dim, float *out) {
    if (hidden > MAX_WIDTH) return 2;
    float *work = work_buffers();
    if (!work) return 1;
    float *buf0 = work, *buf1 = work + MAX_WIDTH * BLOCK, *res = work + 2 * MAX_WIDTH * BLOCK;
    int32_t pix_i[2][BLOCK], pix_o[2][BLOCK];
    float din[6 * BLOCK];  /* the block's direction inputs */
    const long south = 12L * nside * nside;
    if (n > 0) block_pixels(wi, wo, 0, n, nside, table, hidden, pix_i[0], pix_o[0]);
    for (long s = 0, cur = 0; s < n; s += BLOCK, cur ^= 1) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        if (s + BLOCK < n)  /* the next block's rows are fetched while this one runs its MLP */
            block_pixels(wi, wo, s + BLOCK, n, nside, table, hidden, pix_i[cur ^ 1], pix_o[cur ^ 1]);
        if (dir_w) hd_inputs_block(wi, wo, s, n, dir_warp, din);
        for (int k = 0; k < BLOCK; ++k) {  /* the first layer's sums, row by row into res (BLOCK x hidden) */
            const float *ti = table + (long)pix_i[cur][k] * hidden, *to = table + (south + pix_o[cur][k]) * hidden;
            float *pre = res + k * hidden;
            for (int i = 0; i < hidden; ++i) pre[i] = ti[i] + to[i];
            if (dir_w) add_direction_columns(pre, din + k, dir_w, hidden);
        }
        neubrdf_rest(res, hidden, buf0, buf1, first_act, layers, dims, W, b, hidden_act, out_dim, wi, wo, s, m, out);
    }
    free(work);
    return 0;
}

/* NeuBRDF with inverse-distance corner weights (neumat.methods.neubrdf.shared_model: every material of a shared
   model; one grid when t = 1) of directions wi, wo (n x 3): per row its material m (material[k], or `active` without
   material ids), for wi on S+ and the mirrored wo on S- (z clamped at 0 first: healpix.hemisphere_direction) the
   ring pixel, its 4 corner vertices (corners_i / corners_o: (t_c x 12 nside^2 x 4) vertex ids, t_c = t where
   pruning made them per material, else 1), their normalised inverse great-circle distances (healpix.idw_weights,
   distances clamped at 1e-7), and the first layer as the weighted sum of the 8 corner slots' rows of `table`
   (t x slots_per_material rows, hidden: W_i f(s) for S+ slots, W_o f(s) for S- slots, S- slot = vertex +
   south_offset) plus `bias`; then as neubrdf_eval: the direction inputs, the activation, the rest of the MLP, exp;
   0 unless both directions are above the surface. */
int neubrdf_idw_eval(const float *wi, const float *wo, long n, const int32_t *material, int active, int nside,
                     const int32_t *corners_i, const int32_t *corners_o, int per_material, long slots_per_material,
                     long south_offset, const float *vertex_dirs, const float *table, const float *bias, int hidden,
                     const float *dir_w, int dir_warp, int first_act, int layers, const int *dims,
                     const float *const *W, const float *const *b, int hidden_act, int out_dim, float *out) {
    if (hidden > MAX_WIDTH) return 2;
    float *work = work_buffers();
    if (!work) return 1;
    float *buf0 = work, *buf1 = work + MAX_WIDTH * BLOCK, *res = work + 2 * MAX_WIDTH * BLOCK;
    float c[6 * BLOCK], din[6 * BLOCK];
    int32_t pix[2][BLOCK];
    const long P = 12L * nside * nside;
    for (long s = 0; s < n; s += BLOCK) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        for (int k = 0; k < BLOCK; ++k) {
            long r = s + k < m + s ? s + k : s;
            for (int e = 0; e < 2; ++e) {
                const float *w = (e ? wo : wi) + 3 * r;
                float z = w[2] > 0.f ? w[2] : 0.f;
                c[(3 * e) * BLOCK + k] = w[0]; c[(3 * e + 1) * BLOCK + k] = w[1];
                c[(3 * e + 2) * BLOCK + k] = e ? -z : z;
            }
        }
        ring_pixels(c, c + BLOCK, c + 2 * BLOCK, nside, 0, pix[0]);
        ring_pixels(c + 3 * BLOCK, c + 4 * BLOCK, c + 5 * BLOCK, nside, 0, pix[1]);
        if (dir_w) hd_inputs_block(wi, wo, s, n, dir_warp, din);
        for (int k = 0; k < BLOCK; ++k) {
            long r = s + k < m + s ? s + k : s;
            const long mat = material ? material[r] : active;
            float *pre = res + k * hidden;
            for (int i = 0; i < hidden; ++i) pre[i] = bias[i];
            for (int e = 0; e < 2; ++e) {
                const int32_t *vid = (e ? corners_o : corners_i) + ((per_material ? mat : 0) * P + pix[e][k]) * 4;
                const float dx = c[(3 * e) * BLOCK + k], dy = c[(3 * e + 1) * BLOCK + k], dz = c[(3 * e + 2) * BLOCK + k];
                float wgt[4], total = 0.f;
                for (int q = 0; q < 4; ++q) {
                    const float *v = vertex_dirs + 3L * vid[q];
                    float cx = dy * v[2] - dz * v[1], cy = dz * v[0] - dx * v[2], cz = dx * v[1] - dy * v[0];
                    float dist = atan2f(sqrtf(cx * cx + cy * cy + cz * cz), dx * v[0] + dy * v[1] + dz * v[2]);
                    wgt[q] = 1.f / (dist > 1e-7f ? dist : 1e-7f);
                    total += wgt[q];
                }
                for (int q = 0; q < 4; ++q) {
                    const float *row = table + (mat * slots_per_material + vid[q] + (e ? south_offset : 0)) * hidden;
                    const float wq = wgt[q] / total;
                    for (int i = 0; i < hidden; ++i) pre[i] += wq * row[i];
                }
            }
            if (dir_w) add_direction_columns(pre, din + k, dir_w, hidden);
        }
        neubrdf_rest(res, hidden, buf0, buf1, first_act, layers, dims, W, b, hidden_act, out_dim, wi, wo, s, m, out);
    }
    free(work);
    return 0;
}

/* the shading frame (neumat.nn.shading_frames.frame_from_vectors) of a decoded normal (nx, ny, nz) and tangent
   (ux, uy, uz): the unit tangent t and bitangent b = n x t (3 each) that wi, wo are expressed in */
static inline void shading_frame(float nx, float ny, float nz, float ux, float uy, float uz, float *t, float *b) {
    float nn = sqrtf(nx * nx + ny * ny + nz * nz);
    nn = nn > 1e-12f ? nn : 1e-12f;
    nx /= nn; ny /= nn; nz /= nn;
    float dot = ux * nx + uy * ny + uz * nz;
    float tx = ux - dot * nx, ty = uy - dot * ny, tz = uz - dot * nz;
    float tn = sqrtf(tx * tx + ty * ty + tz * tz);
    tn = tn > 1e-12f ? tn : 1e-12f;
    t[0] = tx / tn; t[1] = ty / tn; t[2] = tz / tn;
    b[0] = ny * t[2] - nz * t[1]; b[1] = nz * t[0] - nx * t[2]; b[2] = nx * t[1] - ny * t[0];
}

/* the z of (x, y) lifted to the hemisphere: sqrt(max(1 - x^2 - y^2, 1e-10)) (shading_frames.lift_to_hemisphere) */
static inline float lift_z(float x, float y) {
    float l = 1.f - (x * x + y * y);
    return sqrtf(l > 1e-10f ? l : 1e-10f);
}

/* the Rusinkiewicz half and difference vectors h, d of wi, wo (neumat.nn.angular_texture.half_difference) */
static inline void half_difference(const float *wi, const float *wo, float *h, float *d) {
    float hx = wi[0] + wo[0], hy = wi[1] + wo[1], hz = wi[2] + wo[2];
    float hn = sqrtf(hx * hx + hy * hy + hz * hz);
    hn = hn > 1e-12f ? hn : 1e-12f;
    hx /= hn; hy /= hn; hz /= hn;
    float s2 = hx * hx + hy * hy;
    int pole = s2 < 1e-14f;
    float sq = sqrtf(pole ? 1.f : s2);
    float cp = pole ? 1.f : hx / sq, sp = pole ? 0.f : hy / sq, st = pole ? 0.f : sq, ct = hz;
    float x = cp * wi[0] + sp * wi[1], y = -sp * wi[0] + cp * wi[1];
    h[0] = hx; h[1] = hy; h[2] = hz;
    d[0] = ct * x - st * wi[2]; d[1] = y; d[2] = st * x + ct * wi[2];
}

/* out (C) bilinear at texel coordinates (ix, iy) (>= 0, clamped) of a texture channels-last (H, W, C): grid_sample's
   corner-aligned read; the polar textures, the padded finest latent level and the level atlas */
static inline void bilinear_read(const float *tex, int H, int W, int C, float ix, float iy, float *out) {
    int x0 = (int)ix, y0 = (int)iy;   /* ix, iy >= 0: truncation is floor */
    float fx = ix - (float)x0, fy = iy - (float)y0;
    int x1 = x0 + 1 < W ? x0 + 1 : x0, y1 = y0 + 1 < H ? y0 + 1 : y0;
    const float *a = tex + ((long)y0 * W + x0) * C, *b = tex + ((long)y0 * W + x1) * C;
    const float *c = tex + ((long)y1 * W + x0) * C, *d = tex + ((long)y1 * W + x1) * C;
    float wa = (1.f - fx) * (1.f - fy), wb = fx * (1.f - fy), wc = (1.f - fx) * fy, wd = fx * fy;
    for (int k = 0; k < C; ++k) out[k] = wa * a[k] + wb * b[k] + wc * c[k] + wd * d[k];
}

/* bilinear_read of a texture, its usual channel counts as constants (8: every latent model's latents and
   tripleplane's polar textures, 5: NeuMIP's offset texture, 12: ggx-mipmap's maps, 64: the gated model's polar
   textures): the blend of the four corners then unrolls and vectorises (the offset model's evaluation 1.2x, the
   others' 1.07x, on an AMD EPYC) */
static inline void latent_read(const float *tex, int H, int W, int C, float ix, float iy, float *out) {
    if (C == 8) bilinear_read(tex, H, W, 8, ix, iy, out);
    else if (C == 5) bilinear_read(tex, H, W, 5, ix, iy, out);
    else if (C == 12) bilinear_read(tex, H, W, 12, ix, iy, out);
    else if (C == 64) bilinear_read(tex, H, W, 64, ix, iy, out);
    else bilinear_read(tex, H, W, C, ix, iy, out);
}

/* remainder(x, period) as torch computes it for float32 (fmod, plus the period where the sign differs), for x in
   [-period, period] as atan2 gives (here fmod is x itself, or 0 at +-period) */
static inline float remainder_near(float x, float period) {
    float m = x == period || x == -period ? 0.f : x;
    return m < 0.f ? m + period : m;
}

/* texel coordinates (ix, iy) (BLOCK each), clamped as grid_sample's border padding, of polar points (r, phi)
   (BLOCK each) in a texture of R radii and P azimuths (period: 2 pi or pi), as AngularTexture.read and
   grid_sample compute them */
static inline void polar_texels(const float *r, const float *phi, int R, int P, double period, float *ix, float *iy) {
    const int W = P + 2;
    const float scale = (float)((double)P / period), step = (float)(2.0 / (double)(P + 1)), per = (float)period;
    for (int k = 0; k < BLOCK; ++k) {
        float column = remainder_near(phi[k], per) * scale + 0.5f;
        float gx = column * step - 1.f, gy = (r[k] < 0.f ? 0.f : (r[k] > 1.f ? 1.f : r[k])) * 2.f - 1.f;
        float x = (gx + 1.f) / 2.f * (float)(W - 1), y = (gy + 1.f) / 2.f * (float)(R - 1);
        ix[k] = x < 0.f ? 0.f : (x > (float)(W - 1) ? (float)(W - 1) : x);
        iy[k] = y < 0.f ? 0.f : (y > (float)(R - 1) ? (float)(R - 1) : y);
    }
}

/* rows (count x BLOCK) = bias + weight (count x ds) z (ds x BLOCK): a small decode layer on a block */
static void decode_block(const float *w, const float *bias, const float *zt, int ds, int count, float *rows) {
    for (int j = 0; j < count; ++j) {
        float *o = rows + j * BLOCK;
        for (int k = 0; k < BLOCK; ++k) o[k] = bias[j];
        for (int i = 0; i < ds; ++i) {
            const float c = w[j * ds + i], *zi = zt + i * BLOCK;
            for (int k = 0; k < BLOCK; ++k) o[k] += c * zi[k];
        }
    }
}

/* radii r (BLOCK) warped in place: sum_k softmax(logits)_k r^(0.5 + softplus(raw_k)), r clamped to [1e-9, 1],
   with logits and raw exponents decoded per row (p: 2 terms x BLOCK) (neumat.nn.radial_warp.warp_radius) */
static void warp_block(float *r, const float *p, int terms) {
    float top[BLOCK], total[BLOCK], lr[BLOCK], out[BLOCK];
    for (int k = 0; k < BLOCK; ++k) {
        top[k] = p[k];
        total[k] = out[k] = 0.f;
        float rr = r[k] < 1e-9f ? 1e-9f : (r[k] > 1.f ? 1.f : r[k]);
        lr[k] = fast_log(rr);
    }
    for (int t = 1; t < terms; ++t)
        for (int k = 0; k < BLOCK; ++k) top[k] = p[t * BLOCK + k] > top[k] ? p[t * BLOCK + k] : top[k];
    for (int t = 0; t < terms; ++t)
        for (int k = 0; k < BLOCK; ++k) total[k] += fast_exp(p[t * BLOCK + k] - top[k]);
    for (int t = 0; t < terms; ++t)
        for (int k = 0; k < BLOCK; ++k) {
            float raw = p[(terms + t) * BLOCK + k];
            float alpha = 0.5f + (raw > 20.f ? raw : fast_log(1.f + fast_exp(raw)));
            out[k] += fast_exp(p[t * BLOCK + k] - top[k]) / total[k] * fast_exp(alpha * lr[k]);
        }
    memcpy(r, out, sizeof out);
}

/* the block's uv (rows s .. s + BLOCK - 1 of uv (n x 2); past n, row s again) as u and v (BLOCK each), so that the
   loops over them vectorise (a gather of the clamped row index keeps GCC's loop scalar); a whole block's rows in
   a loop of constant stride */
static inline void block_uv(const float *uv, long s, long n, float *u, float *v) {
    if (s + BLOCK <= n)
        for (int k = 0; k < BLOCK; ++k) { u[k] = uv[2 * (s + k)]; v[k] = uv[2 * (s + k) + 1]; }
    else
        for (int k = 0; k < BLOCK; ++k) {
            const long row = s + k < n ? s + k : s;
            u[k] = uv[2 * row]; v[k] = uv[2 * row + 1];
        }
}

/* texel coordinates (ix, iy) (BLOCK each) of uv (rows s .. s + BLOCK - 1; past n, row s again) in a latent texture
   of h x w texels padded circularly by one: neumat.nn.latent_texture.bilinear_padded's grid, unnormalised and
   clamped as grid_sample's border padding does, float32 step by step as there, without fused multiply-adds (a
   texel coordinate is a large multiple of uv: with them the read differed from torch's in the fifth digit on a
   1K texture) */
__attribute__((optimize("fp-contract=off"), noinline))
static void latent_texels(const float *uv, long s, long n, int h, int w, float *ix, float *iy) {
    const float sx = (float)(2.0 / (double)(w + 1)), sy = (float)(2.0 / (double)(h + 1));
    const float wx = (float)(w + 1), wy = (float)(h + 1);
    float us[BLOCK], vs[BLOCK];
    block_uv(uv, s, n, us, vs);
    for (int k = 0; k < BLOCK; ++k) {
        float u = us[k], v = vs[k];
        u -= floorf(u);  /* torch.remainder(u, 1): fmod (exact), + 1 below 0 (one rounding, as here) */
        v -= floorf(v);
        float x = u * (float)w - 0.5f, y = (1.f - v) * (float)h - 0.5f;
        float gx = (x + 1.f) * sx - 1.f, gy = (y + 1.f) * sy - 1.f;
        float tx = (gx + 1.f) / 2.f * wx, ty = (gy + 1.f) / 2.f * wy;
        ix[k] = tx < 0.f ? 0.f : (tx > wx ? wx : tx);
        iy[k] = ty < 0.f ? 0.f : (ty > wy ? wy : ty);
    }
}

/* Where a kernel's spatial latents z come from (neumat.nn.latent_texture.LatentPyramid.forward's three lookups):
   0: given, z (n x ds); 1: the padded finest level `finest` ((h + 2, w + 2, ds), channels-last) at uv, without
   footprint or lod; 2: trilinear in the atlas of padded levels ((Ha, Wa, ds), channels-last; level l of size
   (size[2 l], size[2 l + 1]) = (W_l, H_l) at origin (origin[2 l], origin[2 l + 1])) at uv and lod; 3: the
   anisotropic filter of a footprint (n x 2 x 2, uv^2) of up to max_probes trilinear probes in that atlas. The
   pointers of per-row data start at the call's first row. */
typedef struct {
    int mode;
    const float *z, *uv, *lod, *footprint;
    const float *finest;
    int h, w;
    const float *atlas;
    int Wa, Ha, levels, max_probes;
    const int *size;
    const float *origin;
} Latents;

/* the clamped texel (ix, iy) in the atlas of level l at (u, fv) (u wrapped into [0, 1), fv = 1 - v wrapped):
   trilinear_flat's grid, float32 step by step as there */
static inline __attribute__((always_inline)) void atlas_texel(const Latents *L, int l, float u, float fv, float *ix,
                                                               float *iy) {
    const float wa = (float)(L->Wa - 1), ha = (float)(L->Ha - 1), sx = 2.f / wa, sy = 2.f / ha;
    float tx = u * (float)L->size[2 * l] - 0.5f, ty = fv * (float)L->size[2 * l + 1] - 0.5f;
    float gx = (tx + L->origin[2 * l]) * sx - 1.f, gy = (ty + L->origin[2 * l + 1]) * sy - 1.f;
    float x = (gx + 1.f) / 2.f * wa, y = (gy + 1.f) / 2.f * ha;
    *ix = x < 0.f ? 0.f : (x > wa ? wa : x);
    *iy = y < 0.f ? 0.f : (y > ha ? ha : y);
}

/* acc (ds) += w[0] times the atlas's bilinear read at (x[0], y[0]) plus w[1] times its read at (x[1], y[1]).
   Not inlined into the block's loop: there, the 12-channel reads of the GGX mip-map ran 1.3x slower */
__attribute__((optimize("fp-contract=off"), noinline))
static void atlas_blend(const Latents *L, int ds, const float *x, const float *y, const float *w, float *acc) {
    float r[2][64];
    for (int e = 0; e < 2; ++e) latent_read(L->atlas, L->Ha, L->Wa, ds, x[e], y[e], r[e]);
    for (int c = 0; c < ds; ++c) acc[c] = acc[c] + (r[0][c] * w[0] + r[1][c] * w[1]);
}

/* trilinear_flat of a block of lookups: for each row k with on[k], acc + k ds (ds) += the bilinear reads of the two
   levels around lod[k] (clamped to the pyramid) at (u[k], v[k]), blended by (1 - t, t) times scale[k]; float32
   step by step as there, without fused multiply-adds. The coordinates of the whole block first (vectorised: one
   row at a time they were most of a footprint's cost), then the reads row by row. */
__attribute__((optimize("fp-contract=off"), noinline))
static void atlas_trilinear_block(const Latents *L, int ds, const float *u, const float *v, const float *lod,
                                  const float *scale, const int *on, float *acc) {
    const float top = (float)(L->levels - 1);
    float ix[2][BLOCK], iy[2][BLOCK], w[2][BLOCK];
    for (int k = 0; k < BLOCK; ++k) {
        const float d = lod[k] < 0.f ? 0.f : (lod[k] > top ? top : lod[k]);
        const float lo = floorf(d), t = d - lo;
        const int l0 = (int)lo, l1 = l0 + 1 < L->levels ? l0 + 1 : L->levels - 1;
        const float uk = u[k] - floorf(u[k]), fv = 1.f - (v[k] - floorf(v[k]));  /* torch.remainder(., 1) */
        w[0][k] = (1.f - t) * scale[k];
        w[1][k] = t * scale[k];
        atlas_texel(L, l0, uk, fv, &ix[0][k], &iy[0][k]);
        atlas_texel(L, l1, uk, fv, &ix[1][k], &iy[1][k]);
    }
    for (int k = 0; k < BLOCK; ++k) {
        if (!on[k]) continue;
        const float x[2] = {ix[0][k], ix[1][k]}, y[2] = {iy[0][k], iy[1][k]}, wk[2] = {w[0][k], w[1][k]};
        atlas_blend(L, ds, x, y, wk, acc + k * ds);
    }
}

/* filter_anisotropic of a block's lookups (rows s .. s + BLOCK - 1, past n row s again) at their uv and footprints
   (2 x 2, uv^2) (neumat.nn.latent_texture: probes along the major axis, each a trilinear read of weight
   1 / probes); rows: BLOCK x ds. Each row's probe count, lod, spacing and axis first, vectorised (atan2, sin, cos
   and log2 by the branch-free forms above, within 1e-7 of libm's: the reads through a footprint 1.05-1.2x), then
   probe by probe the block's trilinear reads (each row's probes added in order, as one row at a time) */
__attribute__((optimize("fp-contract=off"), noinline))
static void atlas_anisotropic_block(const Latents *L, int ds, long s, long n, float *rows) {
    const float W = (float)L->size[0], H = (float)L->size[1];
    float u[BLOCK], v[BLOCK], lod[BLOCK], weight[BLOCK], centre[BLOCK], spacing[BLOCK], ax[BLOCK], ay[BLOCK];
    float pu[BLOCK], pv[BLOCK];
    float f0[BLOCK], f1[BLOCK], f3[BLOCK];  /* the block's footprints (uv^2), gathered so that the loop vectorises */
    int count[BLOCK], on[BLOCK], most = 0;
    block_uv(L->uv, s, n, u, v);
    for (int k = 0; k < BLOCK; ++k) {
        const long row = s + k < n ? s + k : s;
        f0[k] = L->footprint[4 * row]; f1[k] = L->footprint[4 * row + 1]; f3[k] = L->footprint[4 * row + 3];
    }
    for (int k = 0; k < BLOCK; ++k) {
        float a = f0[k] * W * W, b = f1[k] * W * H, c = f3[k] * H * H;  /* the covariance in level-0 texels^2 */
        float mean = (a + c) / 2.f, diff = (a - c) / 2.f, half = sqrtf(diff * diff + b * b);
        float theta = 0.5f * fast_atan2(2.f * b, a - c);
        float up = mean + half, down = mean - half;
        float major = sqrtf(up > 0.f ? up : 0.f), minor = sqrtf(down > 0.f ? down : 0.f);
        minor = minor > 1e-12f ? minor : 1e-12f;
        float probes = ceilf(major / minor);
        probes = probes < 1.f ? 1.f : (probes > (float)L->max_probes ? (float)L->max_probes : probes);
        float per = major / (float)L->max_probes, sigma = minor > per ? minor : per;
        float two_sigma = 2.f * sigma;
        float spread = 12.f * (major * major - sigma * sigma), pairs = probes * probes - 1.f;
        lod[k] = fast_log(two_sigma > 1e-12f ? two_sigma : 1e-12f) * 1.4426950408889634f;
        spacing[k] = sqrtf((spread > 0.f ? spread : 0.f) / (pairs > 1.f ? pairs : 1.f));
        ax[k] = fast_cos(theta);
        ay[k] = fast_sin(theta);
        weight[k] = 1.f / probes;
        centre[k] = (probes - 1.f) / 2.f;
        count[k] = (int)probes;
        most = count[k] > most ? count[k] : most;
    }
    memset(rows, 0, sizeof(float) * BLOCK * ds);
    for (int p = 0; p < most; ++p) {
        for (int k = 0; k < BLOCK; ++k) {
            float offset = ((float)p - centre[k]) * spacing[k];
            pu[k] = u[k] + offset * ax[k] / W;
            pv[k] = v[k] + offset * ay[k] / H;
            on[k] = p < count[k];
        }
        atlas_trilinear_block(L, ds, pu, pv, lod, weight, on, rows);
    }
}

/* the block's latents zt (ds x BLOCK; rows s .. s + BLOCK - 1, past n row s again) from L */
static void latents_block(const Latents *L, long s, long n, int ds, float *zt) {
    float lx[BLOCK], ly[BLOCK], rows[64 * BLOCK];  /* the block's latents row by row, then transposed into zt */
    if (L->mode == 1) latent_texels(L->uv, s, n, L->h, L->w, lx, ly);
    if (L->mode == 2) {
        float u[BLOCK], v[BLOCK], lod[BLOCK], one[BLOCK];
        int on[BLOCK];
        block_uv(L->uv, s, n, u, v);
        for (int k = 0; k < BLOCK; ++k) {
            lod[k] = L->lod[s + k < n ? s + k : s]; one[k] = 1.f; on[k] = 1;
        }
        memset(rows, 0, sizeof(float) * BLOCK * ds);
        atlas_trilinear_block(L, ds, u, v, lod, one, on, rows);
    } else if (L->mode == 3) atlas_anisotropic_block(L, ds, s, n, rows);
    else
        for (int k = 0; k < BLOCK; ++k) {
            long row = s + k < n ? s + k : s;
            float *zr = rows + k * ds;
            if (L->mode == 0) memcpy(zr, L->z + row * ds, ds * sizeof(float));
            else latent_read(L->finest, L->h + 2, L->w + 2, ds, lx[k], ly[k], zr);
        }
    transpose_rows(rows, ds, zt);
}

/* rows s .. s + m - 1 of out (out_dim each) = exp(y) (y: out_dim x BLOCK), 0 where wi.z or wo.z <= 0: the exps over
   the block's whole rows (vectorised; one row at a time they were an eighth of a latent kernel's time) */
static void store_exp(const float *y, int m, int out_dim, const float *wi, const float *wo, long s, float *out) {
    float e[4 * BLOCK], up[BLOCK];
    for (int k = 0; k < m; ++k) up[k] = wi[3 * (s + k) + 2] > 0.f && wo[3 * (s + k) + 2] > 0.f ? 1.f : 0.f;
    for (int j0 = 0; j0 < out_dim; j0 += 4) {  /* up to 4 outputs at a time */
        const int count = out_dim - j0 < 4 ? out_dim - j0 : 4;
        for (int i = 0; i < count * BLOCK; ++i) e[i] = fast_exp(y[j0 * BLOCK + i]);
        if (count == out_dim) write_rows(e, up, m, out_dim, out + (long)out_dim * s);
        else
            for (int k = 0; k < m; ++k)
                for (int j = 0; j < count; ++j) out[out_dim * (s + k) + j0 + j] = up[k] > 0.f ? e[j * BLOCK + k] : 0.f;
    }
}

/* one row's gated latents: out[c] = sum_i read[i ch + c] z[i BLOCK] for c < ch (read: the polar texture's
   channels (D_s, ch), channel fastest; z: the row's latents in a block). Eight channels at a time summed in a
   register (a sum kept in memory waited on each store) */
static inline void gate_row(const float *read, const float *z, int ds, int ch, float *out) {
    typedef float vec8 __attribute__((vector_size(32), aligned(4)));
    int c = 0;
    for (; c + 8 <= ch; c += 8) {
        vec8 acc = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
        for (int i = 0; i < ds; ++i) acc += *(const vec8 *)(read + i * ch + c) * z[i * BLOCK];
        *(vec8 *)(out + c) = acc;
    }
    for (; c < ch; ++c) {
        float acc = 0.f;
        for (int i = 0; i < ds; ++i) acc += read[i * ch + c] * z[i * BLOCK];
        out[c] = acc;
    }
}

/* The multi-scale gated model's decoder (Timonen et al. 2025; neumat.methods.latent_mlp.multiscale, gating on)
   from spatial latents z (`latents`: given or read) and directions wi, wo (n x 3): the shading frame (frame_w:
   6 x ds, already times its weight scale; NULL: none), half and difference vectors, disk polar coordinates,
   radial warps (warp_*: 2 terms x ds; NULL: none), the two polar textures (channels-last, channels ds x dh and
   ds x dd, the model's channel c x ds + i at i x dh + c) gated by z, the MLP on [z_h, z_d], exp; 0 where wi.z or
   wo.z <= 0. Not `gated` (tripleplane): textures of dh and dd channels, the MLP on [a_h, a_d, z]. out: n x
   out_dim. The geometry runs on blocks of rows (vectorised), the texture reads and gating row by row. Returns 1
   without memory, 2 for sizes beyond its buffers. */
int multiscale_eval(const Latents *latents, const float *wi, const float *wo, long n, int ds,
                    const float *frame_w, const float *frame_b, int terms, const float *warp_h_w,
                    const float *warp_h_b, const float *warp_d_w, const float *warp_d_b,
                    int gated, const float *tex_h, int dh, const float *tex_d, int dd, int R, int P,
                    int layers, const int *dims, const float *const *W, const float *const *b, int hidden_act,
                    int out_dim, float *out) {
    const double two_pi = 6.283185307179586, pi = 3.141592653589793;
    const int gate = gated ? ds : 1;  /* the textures' channels: channels x D_s gated, the channels alone not */
    if (ds > 64 || dh * gate > 1024 || dd * gate > 1024 || terms > 8 || dh + dd + ds > MAX_WIDTH) return 2;
    float *work = work_buffers();
    if (!work) return 1;
    float *buf0 = work, *buf1 = work + MAX_WIDTH * BLOCK, *zt = work + 2 * MAX_WIDTH * BLOCK;  /* zt: ds x BLOCK */
    float *rows = work + 3 * MAX_WIDTH * BLOCK;  /* the MLP's inputs row by row (BLOCK x width), then transposed */
    const int width = gated ? dh + dd : dh + dd + ds;
    /* a block's directions' components, polar coordinates, decoded rows (16 x BLOCK) and texel coordinates */
    float vix[BLOCK], viy[BLOCK], viz[BLOCK], vox[BLOCK], voy[BLOCK], voz[BLOCK];
    float r_h[BLOCK], r_d[BLOCK], phi_h[BLOCK], phi_d[BLOCK], p[16 * BLOCK], tc[4 * BLOCK];
    float read_h[1024], read_d[1024];
    for (long s = 0; s < n; s += BLOCK) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        latents_block(latents, s, n, ds, zt);
        for (int k = 0; k < BLOCK; ++k) {
            long row = s + (k < m ? k : 0);
            vix[k] = wi[3 * row]; viy[k] = wi[3 * row + 1]; viz[k] = wi[3 * row + 2];
            vox[k] = wo[3 * row]; voy[k] = wo[3 * row + 1]; voz[k] = wo[3 * row + 2];
        }
        if (frame_w) {
            decode_block(frame_w, frame_b, zt, ds, 6, p);
            for (int k = 0; k < BLOCK; ++k) {  /* x, y in the frame (the lift below gives z) */
                float t[3], b[3];
                shading_frame(p[k], p[BLOCK + k], p[2 * BLOCK + k], p[3 * BLOCK + k], p[4 * BLOCK + k],
                              p[5 * BLOCK + k], t, b);
                float a0 = vix[k], a1 = viy[k], a2 = viz[k], c0 = vox[k], c1 = voy[k], c2 = voz[k];
                vix[k] = a0 * t[0] + a1 * t[1] + a2 * t[2]; viy[k] = a0 * b[0] + a1 * b[1] + a2 * b[2];
                vox[k] = c0 * t[0] + c1 * t[1] + c2 * t[2]; voy[k] = c0 * b[0] + c1 * b[1] + c2 * b[2];
            }
        }
        for (int k = 0; k < BLOCK; ++k) {  /* lift, half and difference vectors, disk polar coordinates */
            float a[3] = {vix[k], viy[k], lift_z(vix[k], viy[k])}, c[3] = {vox[k], voy[k], lift_z(vox[k], voy[k])};
            float h[3], d[3];
            half_difference(a, c, h, d);
            float hx = h[0], hy = h[1], dx = d[0], dy = d[1];
            float rh2 = hx * hx + hy * hy, rd2 = dx * dx + dy * dy;
            int ph = rh2 < 1e-14f, pd = rd2 < 1e-14f;
            float rh = sqrtf(ph ? 1.f : rh2), rd = sqrtf(pd ? 1.f : rd2);
            r_h[k] = ph ? 0.f : (rh < 1.f ? rh : 1.f);
            r_d[k] = pd ? 0.f : (rd < 1.f ? rd : 1.f);
            phi_h[k] = ph ? 0.f : hy; vix[k] = ph ? 1.f : hx;  /* atan2's arguments (wi is no longer needed) */
            phi_d[k] = pd ? 0.f : dy; viy[k] = pd ? 1.f : dx;
        }
        for (int k = 0; k < BLOCK; ++k) {
            phi_h[k] = remainder_near(fast_atan2(phi_h[k], vix[k]), (float)two_pi);
            phi_d[k] = remainder_near(fast_atan2(phi_d[k], viy[k]), (float)pi);
        }
        if (warp_h_w) {
            decode_block(warp_h_w, warp_h_b, zt, ds, 2 * terms, p);
            warp_block(r_h, p, terms);
            decode_block(warp_d_w, warp_d_b, zt, ds, 2 * terms, p);
            warp_block(r_d, p, terms);
        }
        polar_texels(r_h, phi_h, R, P, two_pi, tc, tc + BLOCK);  /* texel (x, y) of the half, then the diff texture */
        polar_texels(r_d, phi_d, R, P, pi, tc + 2 * BLOCK, tc + 3 * BLOCK);
        for (int k = 0; k < BLOCK; ++k) {
            latent_read(tex_h, R, P + 2, dh * gate, tc[k], tc[BLOCK + k], read_h);
            latent_read(tex_d, R, P + 2, dd * gate, tc[2 * BLOCK + k], tc[3 * BLOCK + k], read_d);
            float *row = rows + k * width;
            if (!gated) {  /* tripleplane: the MLP reads [a_h, a_d, z] */
                memcpy(row, read_h, sizeof(float) * dh);
                memcpy(row + dh, read_d, sizeof(float) * dd);
                for (int i = 0; i < ds; ++i) row[dh + dd + i] = zt[i * BLOCK + k];
                continue;
            }
            gate_row(read_h, zt + k, ds, dh, row);  /* z_h, then z_d */
            gate_row(read_d, zt + k, ds, dd, row + dh);
        }
        transpose_rows(rows, width, buf0);
        const float *restrict y = mlp_block(buf0, buf1, layers, dims, W, b, hidden_act, m);
        store_exp(y, m, out_dim, wi, wo, s, out);
    }
    free(work);
    return 0;
}

/* NeuMIP (Kuznetsov et al. 2021; neumat.methods.latent_mlp.neumip without offset module; neural-appearance's
   BRDF decoder): the MLP on [z, wi, wo], or with `rusinkiewicz` on [z, h, d], with wi and wo first moved into
   each of `frames` shading frames decoded from z (frame_w: 6 frames x ds, already times its weight scale; 0
   frames: none), then [z, wi in every frame, wo in every frame]; exp, 0 where wi.z or wo.z <= 0 (the directions
   as given); z from `latents`. out: n x out_dim. */
int neumip_eval(const Latents *latents, const float *wi, const float *wo, long n, int ds, int frames,
                const float *frame_w, const float *frame_b, int rusinkiewicz, int layers, const int *dims,
                const float *const *W, const float *const *b, int hidden_act, int out_dim, float *out) {
    const int dirs_n = 6 * (frames > 1 ? frames : 1);
    if (ds > 64 || frames > 4 || ds + dirs_n > MAX_WIDTH) return 2;
    float *work = work_buffers();
    if (!work) return 1;
    float *buf0 = work, *buf1 = work + MAX_WIDTH * BLOCK, *zt = work + 2 * MAX_WIDTH * BLOCK;  /* zt: ds x BLOCK */
    float v[6 * BLOCK], p[24 * BLOCK];  /* the block's wi, wo by component; the frames' decoded rows */
    for (long s = 0; s < n; s += BLOCK) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        latents_block(latents, s, n, ds, zt);
        memcpy(buf0, zt, sizeof(float) * ds * BLOCK);
        float *dirs = buf0 + ds * BLOCK;  /* the direction rows: wi in frames 0 .. F - 1, then wo in them */
        for (int k = 0; k < BLOCK; ++k) {
            long row = s + (k < m ? k : 0);
            for (int j = 0; j < 3; ++j) { v[j * BLOCK + k] = wi[3 * row + j]; v[(3 + j) * BLOCK + k] = wo[3 * row + j]; }
        }
        if (frames == 0) memcpy(dirs, v, sizeof(float) * 6 * BLOCK);
        else {  /* the frames' decode layer on the block, then each frame's basis and both directions in it */
            decode_block(frame_w, frame_b, zt, ds, 6 * frames, p);
            for (int f = 0; f < frames; ++f) {
                const float *q = p + 6 * f * BLOCK;
                float *di = dirs + 3 * f * BLOCK, *dk = dirs + 3 * (frames + f) * BLOCK;
                for (int k = 0; k < BLOCK; ++k) {
                    float t[3], b[3];
                    shading_frame(q[k], q[BLOCK + k], q[2 * BLOCK + k], q[3 * BLOCK + k], q[4 * BLOCK + k],
                                  q[5 * BLOCK + k], t, b);
                    for (int e = 0; e < 2; ++e) {
                        const float *w = v + 3 * e * BLOCK;
                        float *o = e ? dk : di;
                        float x = w[k] * t[0] + w[BLOCK + k] * t[1] + w[2 * BLOCK + k] * t[2];
                        float y = w[k] * b[0] + w[BLOCK + k] * b[1] + w[2 * BLOCK + k] * b[2];
                        o[k] = x; o[BLOCK + k] = y; o[2 * BLOCK + k] = lift_z(x, y);
                    }
                }
            }
        }
        if (rusinkiewicz) {  /* one frame at most: h, d of (wi, wo) */
            for (int k = 0; k < BLOCK; ++k) {
                float a[3] = {dirs[k], dirs[BLOCK + k], dirs[2 * BLOCK + k]};
                float c[3] = {dirs[3 * BLOCK + k], dirs[4 * BLOCK + k], dirs[5 * BLOCK + k]}, h[3], d[3];
                half_difference(a, c, h, d);
                for (int j = 0; j < 3; ++j) { dirs[j * BLOCK + k] = h[j]; dirs[(3 + j) * BLOCK + k] = d[j]; }
            }
        }
        const float *restrict y = mlp_block(buf0, buf1, layers, dims, W, b, hidden_act, m);
        store_exp(y, m, out_dim, wi, wo, s, out);
    }
    free(work);
    return 0;
}

/* NeuMIP's offset module (Kuznetsov et al. 2021; neumat.methods.latent_mlp.neumip.NeuMIP.offset_uv): the
   lookup point uv' = uv + (h wo.xy) / max(wo.z, min_cos), h = MLP_o([z_o, wo]) / size, z_o from `offset` (the
   offset pyramid at the query's uv, with its footprint or lod; its uv is the uv here); uv_out: n x 2. */
int neumip_offset_uv(const Latents *offset, const float *wo, long n, int channels, float size, float min_cos,
                     int layers, const int *dims, const float *const *W, const float *const *b, int hidden_act,
                     float *uv_out) {
    if (channels > 64 || channels + 3 > MAX_WIDTH) return 2;
    float *work = work_buffers();
    if (!work) return 1;
    float *buf0 = work, *buf1 = work + MAX_WIDTH * BLOCK, *zt = work + 2 * MAX_WIDTH * BLOCK;
    for (long s = 0; s < n; s += BLOCK) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        latents_block(offset, s, n, channels, zt);
        memcpy(buf0, zt, sizeof(float) * channels * BLOCK);
        for (int k = 0; k < BLOCK; ++k) {
            long row = s + (k < m ? k : 0);
            for (int j = 0; j < 3; ++j) buf0[(channels + j) * BLOCK + k] = wo[3 * row + j];
        }
        const float *restrict y = mlp_block(buf0, buf1, layers, dims, W, b, hidden_act, m);
        for (int k = 0; k < m; ++k) {
            const long row = s + k;
            const float h = y[k] / size, c = wo[3 * row + 2] > min_cos ? wo[3 * row + 2] : min_cos;
            uv_out[2 * row] = offset->uv[2 * row] + (h * wo[3 * row]) / c;
            uv_out[2 * row + 1] = offset->uv[2 * row + 1] + (h * wo[3 * row + 1]) / c;
        }
    }
    free(work);
    return 0;
}

/* Fresnel reflectance at cos(wi, h) for `ggx_eval`'s modes: 1 conductor (complex IOR eta + i k per channel,
   Mitsuba 3's form as neumat.reflectance.microfacet.fresnel_conductor), 2 dielectric (eta[0]: inside over outside),
   3 Schlick (f0 per channel), 0 none; into f (3) */
static inline void ggx_fresnel(int mode, float cos_d, const float *eta, const float *k, const float *f0, float *f) {
    const float c = fminf(fmaxf(cos_d, 0.f), 1.f), c2 = c * c, s2 = 1.f - c2;
    for (int j = 0; j < 3; ++j) {
        if (mode == 1) {
            float e2k2 = eta[j] * eta[j] - k[j] * k[j], four = 4.f * eta[j] * eta[j] * k[j] * k[j];
            float t1 = e2k2 - s2, a2pb2 = sqrtf(t1 * t1 + four), a = sqrtf(fmaxf(0.5f * (a2pb2 + t1), 0.f));
            float term1 = a2pb2 + c2, term2 = (2.f * c) * a, rs = (term1 - term2) / (term1 + term2);
            float term3 = a2pb2 * c2 + s2 * s2, term4 = term2 * s2;
            f[j] = 0.5f * (rs + rs * (term3 - term4) / (term3 + term4));
        } else if (mode == 2) {
            float e = cos_d >= 0.f ? eta[0] : 1.f / eta[0], ci = fminf(fabsf(cos_d), 1.f);
            float st2 = (1.f - ci * ci) / (e * e), ct = sqrtf(fmaxf(1.f - st2, 0.f));
            float rs = (ci - e * ct) / (ci + e * ct), rp = (e * ci - ct) / (e * ci + ct);
            f[j] = st2 >= 1.f ? 1.f : 0.5f * (rs * rs + rp * rp);
        } else if (mode == 3) {
            float w = 1.f - c;
            f[j] = f0[j] + (1.f - f0[j]) * (w * w * w * w * w);
        } else f[j] = 1.f;
    }
}

/* GGX reflection (neumat.reflectance.analytic.GGX) of directions wi, wo (n x 3): D(h) G1(wi) G1(wo) F(wi.h) /
   (4 cos_i cos_o) with alphas (ax, ay) and Fresnel `mode` (ggx_fresnel), plus a Lambertian term diffuse_pi (3: the
   albedo / pi; the fitted GGX baseline's); 0 unless both are above the surface. out: n x 3. */
int ggx_eval(const float *wi, const float *wo, long n, float ax, float ay, int mode, const float *eta, const float *k,
             const float *f0, const float *diffuse_pi, float *out) {
    const float tiny = 1.17549435e-38f, inv_pi = 0.3183098861837907f;
    float res[3 * BLOCK], keep[BLOCK];
    for (long s = 0; s < n; s += BLOCK) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        for (int k2 = 0; k2 < BLOCK; ++k2) {
            const long row = s + (k2 < m ? k2 : 0);
            const float *a = wi + 3 * row, *b = wo + 3 * row;
            float hx = a[0] + b[0], hy = a[1] + b[1], hz = a[2] + b[2];
            float hl = fmaxf(sqrtf(hx * hx + hy * hy + hz * hz), 1e-12f);
            hx /= hl; hy /= hl; hz /= hl;
            float e = (hx / ax) * (hx / ax) + (hy / ay) * (hy / ay) + hz * hz;
            float d = hz > 0.f ? inv_pi / (ax * ay * e * e) : 0.f;
            float zi = fmaxf(a[2], 0.f), zo = fmaxf(b[2], 0.f);
            float ri = sqrtf(a[2] * a[2] + (ax * a[0]) * (ax * a[0]) + (ay * a[1]) * (ay * a[1]));
            float ro = sqrtf(b[2] * b[2] + (ax * b[0]) * (ax * b[0]) + (ay * b[1]) * (ay * b[1]));
            float g = (2.f * zi / fmaxf(zi + ri, tiny)) * (2.f * zo / fmaxf(zo + ro, tiny));
            float spec = d * g / fmaxf(4.f * a[2] * b[2], tiny), f[3];
            ggx_fresnel(mode, a[0] * hx + a[1] * hy + a[2] * hz, eta, k, f0, f);
            for (int j = 0; j < 3; ++j) res[j * BLOCK + k2] = f[j] * spec + diffuse_pi[j];
            keep[k2] = a[2] > 0.f && b[2] > 0.f ? 1.f : 0.f;
        }
        write_rows(res, keep, m, 3, out + 3 * s);
    }
    return 0;
}

/* torch's softplus (beta 1, threshold 20) by the kernels' exp and log */
static inline float softplus(float x) { return x > 20.f ? x : fast_log(1.f + fast_exp(x)); }

/* The GGX parameter mip-map (neumat.methods.latent_mlp.ggx_mipmap): its 12 parameters from `latents` (albedo and
   F0 through softplus, normal slopes, log alphas clamped to [1e-3, 2], the tangent's rotation as an angle-doubled
   vector), a diffuse plus anisotropic GGX lobe with Schlick's Fresnel in the frame they give, times the cosine
   ratio; 0 where wi.z, wo.z or either in the frame is <= 0. out: n x 3. The tangent's rotation by the half-angle
   vector (no atan2, sin, cos), so that the loop over a block vectorises. */
int ggx_mipmap_eval(const Latents *latents, const float *wi, const float *wo, long n, float *out) {
    const float inv_pi = 0.3183098861837907f, tiny = 1.17549435e-38f;
    float *work = work_buffers();
    if (!work) return 1;
    float *zt = work, *res = work + MAX_WIDTH * BLOCK, keep[BLOCK];
    for (long s = 0; s < n; s += BLOCK) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        latents_block(latents, s, n, 12, zt);
        for (int k = 0; k < BLOCK; ++k) {
            const long row = s + (k < m ? k : 0);
            float p[12];
            for (int c = 0; c < 12; ++c) p[c] = zt[c * BLOCK + k];
            float nx = p[6], ny = p[7], nz = 1.f, nn = sqrtf(nx * nx + ny * ny + nz * nz);
            nx /= nn; ny /= nn; nz /= nn;
            float tx = 1.f - nx * nx, ty = -nx * ny, tz = -nx * nz;  /* (1, 0, 0) made orthogonal to n */
            float tl = sqrtf(fmaxf(tx * tx + ty * ty + tz * tz, 1e-24f));
            tx /= tl; ty /= tl; tz /= tl;
            float bx = ny * tz - nz * ty, by = nz * tx - nx * tz, bz = nx * ty - ny * tx;
            float a = p[10], c = p[11], r = sqrtf(a * a + c * c);  /* phi = atan2(c, a) / 2 */
            float sgn = c < 0.f || (c == 0.f && signbit(c)) ? -1.f : 1.f;
            float hx = a >= 0.f ? r + a : sgn * c, hy = a >= 0.f ? c : sgn * (r - a);
            float hl = sqrtf(hx * hx + hy * hy);
            float cphi = hl > 0.f ? hx / hl : 1.f, sphi = hl > 0.f ? hy / hl : 0.f;
            float ux = cphi * tx + sphi * bx, uy = cphi * ty + sphi * by, uz = cphi * tz + sphi * bz;
            float vx = ny * uz - nz * uy, vy = nz * ux - nx * uz, vz = nx * uy - ny * ux;
            float ax = fminf(fmaxf(fast_exp(p[8]), 1e-3f), 2.f), ay = fminf(fmaxf(fast_exp(p[9]), 1e-3f), 2.f);
            const float *w0 = wi + 3 * row, *w1 = wo + 3 * row;
            float li[3] = {w0[0] * ux + w0[1] * uy + w0[2] * uz, w0[0] * vx + w0[1] * vy + w0[2] * vz,
                           w0[0] * nx + w0[1] * ny + w0[2] * nz};
            float lo[3] = {w1[0] * ux + w1[1] * uy + w1[2] * uz, w1[0] * vx + w1[1] * vy + w1[2] * vz,
                           w1[0] * nx + w1[1] * ny + w1[2] * nz};
            int up = w0[2] > 0.f && w1[2] > 0.f && li[2] > 0.f && lo[2] > 0.f;
            keep[k] = up ? 1.f : 0.f;
            if (!up) { li[0] = li[1] = lo[0] = lo[1] = 0.f; li[2] = lo[2] = 1.f; }
            float qx = li[0] + lo[0], qy = li[1] + lo[1], qz = li[2] + lo[2];
            float ql = fmaxf(sqrtf(qx * qx + qy * qy + qz * qz), 1e-12f);
            qx /= ql; qy /= ql; qz /= ql;
            float e = (qx / ax) * (qx / ax) + (qy / ay) * (qy / ay) + qz * qz;
            float d = qz > 0.f ? 1.f / (3.141592653589793f * ax * ay * e * e) : 0.f;
            float zi = fmaxf(li[2], 0.f), zo = fmaxf(lo[2], 0.f);
            float ri = sqrtf(li[2] * li[2] + (ax * li[0]) * (ax * li[0]) + (ay * li[1]) * (ay * li[1]));
            float ro = sqrtf(lo[2] * lo[2] + (ax * lo[0]) * (ax * lo[0]) + (ay * lo[1]) * (ay * lo[1]));
            float g = (2.f * zi / fmaxf(zi + ri, tiny)) * (2.f * zo / fmaxf(zo + ro, tiny));
            float spec = d * g / fmaxf(4.f * li[2] * lo[2], tiny);
            float cd = fminf(fmaxf(li[0] * qx + li[1] * qy + li[2] * qz, 0.f), 1.f), f1 = 1.f - cd;
            float f5 = f1 * f1 * f1 * f1 * f1;
            float ratio = 0.5f * (li[2] / fmaxf(w0[2], 1e-6f) + lo[2] / fmaxf(w1[2], 1e-6f));
            for (int j = 0; j < 3; ++j) {
                float f0 = softplus(p[3 + j]);
                res[j * BLOCK + k] = (softplus(p[j]) * inv_pi + (f0 + (1.f - f0) * f5) * spec) * ratio;
            }
        }
        write_rows(res, keep, m, 3, out + 3 * s);
    }
    free(work);
    return 0;
}

/* A `neumat.reflectance.measured.Marginal2D` table as `rgl_eval` reads it: S parameter slices of H x W cells, K
   channels (channel c of slice s at data[c] + s H W), and where it warps, the conditional CDFs cond (S x H x
   (W - 1)) and the marginal marg (S x (H - 1)) */
typedef struct {
    const float *data[3];
    int H, W, K;
    const float *cond, *marg;
} Table2D;

/* torch.lerp(a, b, w) */
static inline float lerp(float a, float b, float w) { return w < 0.5f ? a + w * (b - a) : b - (b - a) * (1.f - w); }

/* max and min as selects: unlike fmaxf / fminf (NaN rules), GCC vectorises them (inputs here are finite) */
static inline float max_f(float a, float b) { return a > b ? a : b; }
static inline float min_f(float a, float b) { return a < b ? a : b; }

/* (1 - c)^5 of a cosine c clamped to [0, 1]: Schlick's weight */
static inline float schlick_weight(float c) {
    const float w = 1.f - min_f(max_f(c, 0.f), 1.f), w2 = w * w;
    return w2 * w2 * w;
}

/* one channel of the principled BRDF times the cosine ratio (svbrdf_eval): base colour clamped, its diffuse part
   (diffuse: the channel-independent (1 - metallic)(1 - F_d(cos_i)) times the cos_o factor) plus the GGX term spec
   times lerp(F_d, F_m, metallic) (Schlick weight wd), 0 unless up */
static inline float principled_channel(float base, float diffuse, float fd, float wd, float metal, float spec, int up,
                                       float ratio) {
    base = min_f(max_f(base, 0.f), 1.f);
    const float f = diffuse * base + lerp(fd, base + (1.f - base) * wd, metal) * spec;
    return up ? f * ratio : 0.f;
}

/* The principled SVBRDF's point value (neumat.reflectance.svbrdf.SVBRDF.eval_point) averaged over `samples`
   positions per query (neumat.reflectance.footprint_filter.filtered_eval; one sample: the point value itself).
   maps: the PBR stack padded circularly by one texel, (h + 2, w + 2, 8) channels-last (base colour 3, normal 3,
   roughness, metalness); pts: n * samples x 2 uv, query-major; wi, wo: n x 3 world directions. Per position: the maps
   bilinear, the unit normal's shading frame (the tangent +u projected onto its plane), wi and wo in it, the
   isotropic principled BRDF (neumat.reflectance.microfacet.principled_eval at the `specular` level) times the cosine
   ratio (symmetrise: the mean of wi's and wo's, else wi's), 0 unless both directions are above the geometric and the
   shading surface. out: n x 3, the mean over each query's positions. Why: a latent-texture fit's targets are 32 such
   positions per query, in torch about half of a CPU training step. */
int svbrdf_eval(const float *maps, int h, int w, const float *wi, const float *wo, const float *pts, long n,
                int samples, float specular, int symmetrise, float *out) {
    const float tiny = 1.17549435e-38f, pi = 3.14159265358979f;
    const float f0d = 0.08f * min_f(max_f(specular, 0.f), 1.f), diffuse_den = pi * (1.f - (f0d + (1.f - f0d) / 21.f));
    const long total = n * (long)samples;
    float ix[BLOCK], iy[BLOCK], p[8 * BLOCK], dirs[6 * BLOCK], res[3 * BLOCK];
    for (long i = 0; i < 3 * n; ++i) out[i] = 0.f;
    for (long s = 0; s < total; s += BLOCK) {
        const int m = total - s < BLOCK ? (int)(total - s) : BLOCK;
        latent_texels(pts, s, total, h, w, ix, iy);
        /* gather: each position's maps and its query's directions, feature-major, so that the arithmetic below
           runs over contiguous rows of BLOCK values (vectorised) */
        for (int k = 0; k < BLOCK; ++k) {
            float t[8];
            bilinear_read(maps, h + 2, w + 2, 8, ix[k], iy[k], t);
            for (int c = 0; c < 8; ++c) p[c * BLOCK + k] = t[c];
            const long row = (s + (k < m ? k : 0)) / samples;
            for (int c = 0; c < 3; ++c) {
                dirs[c * BLOCK + k] = wi[3 * row + c];
                dirs[(3 + c) * BLOCK + k] = wo[3 * row + c];
            }
        }
        for (int k = 0; k < BLOCK; ++k) {
            const float a0 = dirs[k], a1 = dirs[BLOCK + k], a2 = dirs[2 * BLOCK + k];
            const float b0 = dirs[3 * BLOCK + k], b1 = dirs[4 * BLOCK + k], b2 = dirs[5 * BLOCK + k];
            float nx = p[3 * BLOCK + k], ny = p[4 * BLOCK + k], nz = p[5 * BLOCK + k];
            const float nl = max_f(sqrtf(nx * nx + ny * ny + nz * nz), 1e-12f);
            nx /= nl; ny /= nl; nz /= nl;
            float tx = 1.f - nx * nx, ty = -nx * ny, tz = -nx * nz;  /* +u minus its normal component */
            const float tl = sqrtf(max_f(tx * tx + ty * ty + tz * tz, 1e-24f));
            tx /= tl; ty /= tl; tz /= tl;
            const float bx = ny * tz - nz * ty, by = nz * tx - nx * tz, bz = nx * ty - ny * tx;
            const float lix = a0 * tx + a1 * ty + a2 * tz, liy = a0 * bx + a1 * by + a2 * bz;
            const float liz = a0 * nx + a1 * ny + a2 * nz;
            const float lox = b0 * tx + b1 * ty + b2 * tz, loy = b0 * bx + b1 * by + b2 * bz;
            const float loz = b0 * nx + b1 * ny + b2 * nz;
            const float metal = min_f(max_f(p[7 * BLOCK + k], 0.f), 1.f), r = min_f(max_f(p[6 * BLOCK + k], 0.f), 1.f);
            const float al = max_f(r * r, 1e-3f);
            /* diffuse: (1 - metallic)(1 - F_d(cos_i)) base (1 - F_d(cos_o)) / (pi (1 - F_d_avg)), both up */
            const float albedo = (1.f - metal) * (1.f - (f0d + (1.f - f0d) * schlick_weight(liz)));
            const float dscale = liz > 0.f && loz > 0.f ?
                (1.f - (f0d + (1.f - f0d) * schlick_weight(loz))) / diffuse_den : 0.f;
            /* GGX: D(h) G1(wi) G1(wo) / (4 cos_i cos_o), Fresnel lerp(F_d, F_m, metallic) at cos(wi, h) */
            float hx = lix + lox, hy = liy + loy, hz = liz + loz;
            const float hl = max_f(sqrtf(hx * hx + hy * hy + hz * hz), 1e-12f);
            hx /= hl; hy /= hl; hz /= hl;
            const float e = (hx / al) * (hx / al) + (hy / al) * (hy / al) + hz * hz;
            const float d = hz > 0.f ? 1.f / (pi * al * al * e * e) : 0.f;
            const float zi = max_f(liz, 0.f), zo = max_f(loz, 0.f);
            const float ri = sqrtf(liz * liz + (al * lix) * (al * lix) + (al * liy) * (al * liy));
            const float ro = sqrtf(loz * loz + (al * lox) * (al * lox) + (al * loy) * (al * loy));
            const float g = (2.f * zi / max_f(zi + ri, tiny)) * (2.f * zo / max_f(zo + ro, tiny));
            const float spec = d * g / max_f(4.f * liz * loz, tiny);
            const float wd = schlick_weight(lix * hx + liy * hy + liz * hz), fd = f0d + (1.f - f0d) * wd;
            const int up = a2 > 0.f && b2 > 0.f && liz > 0.f && loz > 0.f;
            const float ratio_i = liz / max_f(a2, 1e-12f);
            const float ratio = symmetrise ? 0.5f * (ratio_i + loz / max_f(b2, 1e-12f)) : ratio_i;
            res[k] = principled_channel(p[k], albedo * dscale, fd, wd, metal, spec, up, ratio);
            res[BLOCK + k] = principled_channel(p[BLOCK + k], albedo * dscale, fd, wd, metal, spec, up, ratio);
            res[2 * BLOCK + k] = principled_channel(p[2 * BLOCK + k], albedo * dscale, fd, wd, metal, spec, up, ratio);
        }
        for (int k = 0; k < m; ++k) {
            float *o = out + 3 * ((s + k) / samples);
            o[0] += res[k]; o[1] += res[BLOCK + k]; o[2] += res[2 * BLOCK + k];
        }
    }
    for (long i = 0; i < 3 * n; ++i) out[i] /= (float)samples;
    return 0;
}

/* the value at flat index i of a table (S x size per slice) interpolated over the parameter slices sl (count) */
static inline float sliced(const float *t, long size, const int *sl, const float *w, int count, long i) {
    float v = 0.f;
    for (int c = 0; c < count; ++c) v += t[sl[c] * size + i] * w[c];
    return v;
}

/* the parameter slices of value p on a sorted grid vals (size), as Marginal2D._slices: (lower index, weight of
   the upper one) */
static inline void grid_step(const float *vals, int size, float p, int *i0, float *w1) {
    int i = 0;
    while (i < size && vals[i] < p) ++i;  /* torch.searchsorted (left) */
    i = i < 1 ? 1 : (i > size - 1 ? size - 1 : i);
    *i0 = i - 1;
    float w = (p - vals[i - 1]) / (vals[i] - vals[i - 1]);
    *w1 = w < 0.f ? 0.f : (w > 1.f ? 1.f : w);
}

/* a Marginal2D position's patch: cell (ix, iy) and the position in it (fx, fy), NaN taken as 0 */
static inline void patch_of(const Table2D *t, float px, float py, int *ix, int *iy, float *fx, float *fy) {
    px = isnan(px) ? 0.f : px; py = isnan(py) ? 0.f : py;
    float x = fminf(fmaxf(px, 0.f), 1.f) * (float)(t->W - 1), y = fminf(fmaxf(py, 0.f), 1.f) * (float)(t->H - 1);
    *ix = (int)x < t->W - 2 ? (int)x : t->W - 2;
    *iy = (int)y < t->H - 2 ? (int)y : t->H - 2;
    *fx = x - (float)*ix; *fy = y - (float)*iy;
}

/* Marginal2D.eval: channel values (K) at (px, py) over slices sl (count, weights w) */
static inline void table_eval(const Table2D *t, float px, float py, const int *sl, const float *w, int count,
                              float *out) {
    int ix, iy;
    float fx, fy;
    patch_of(t, px, py, &ix, &iy, &fx, &fy);
    const long size = (long)t->H * t->W, cell = (long)iy * t->W + ix;
    for (int c = 0; c < t->K; ++c) {
        const float *d = t->data[c];
        float v00 = sliced(d, size, sl, w, count, cell), v10 = sliced(d, size, sl, w, count, cell + 1);
        float v01 = sliced(d, size, sl, w, count, cell + t->W), v11 = sliced(d, size, sl, w, count, cell + t->W + 1);
        out[c] = lerp(lerp(v00, v10, fx), lerp(v01, v11, fx), fy);
    }
}

/* Marginal2D.invert (channel 0): the uniform coordinates (sx, sy) of a warped point (px, py) */
static inline void table_invert(const Table2D *t, float px, float py, const int *sl, const float *w, int count,
                                float *sx_out, float *sy_out) {
    int ix, iy;
    float fx, fy;
    patch_of(t, px, py, &ix, &iy, &fx, &fy);
    const long size = (long)t->H * t->W, cell = (long)iy * t->W + ix, wm = t->W - 1;
    const float *d = t->data[0];
    float v00 = sliced(d, size, sl, w, count, cell), v10 = sliced(d, size, sl, w, count, cell + 1);
    float v01 = sliced(d, size, sl, w, count, cell + t->W), v11 = sliced(d, size, sl, w, count, cell + t->W + 1);
    float c0 = lerp(v00, v01, fy), c1 = lerp(v10, v11, fy);
    float sx = fx * lerp(c0, c1, 0.5f * fx) / (float)wm;
    const long csize = (long)t->H * wm, row0 = (long)iy * wm, prev = ix > 0 ? ix - 1 : 0;
    float b0 = sliced(t->cond, csize, sl, w, count, row0 + prev);
    float b1 = sliced(t->cond, csize, sl, w, count, row0 + wm + prev);
    float r0 = sliced(t->cond, csize, sl, w, count, row0 + wm - 1);
    float r1 = sliced(t->cond, csize, sl, w, count, row0 + 2 * wm - 1);
    if (ix > 0) sx += lerp(b0, b1, fy);
    sx /= lerp(r0, r1, fy);
    float sy = fy * lerp(r0, r1, 0.5f * fy) / (float)(t->H - 1);
    if (iy > 0) sy += sliced(t->marg, t->H - 1, sl, w, count, iy - 1);
    *sx_out = sx; *sy_out = sy;
}

/* elevation of a unit vector: atan2(sqrt(x^2 + y^2), z), as accurate near the pole as Mitsuba's 2 asin(|d - z| / 2)
   and inline (libm's asinf and atan2f were half of `rgl_eval`'s time) */
static inline float elevation(float x, float y, float z) { return fast_atan2(sqrtf(x * x + y * y), z); }

/* a * -sign(b), the sign bit deciding (Dr.Jit's mulsign_neg) */
static inline float mulsign_neg(float a, float b) { return signbit(b) ? a : -a; }

/* An RGL measured BRDF (neumat.reflectance.measured.RglMaterial.eval, Mitsuba 3's `measured`): directions folded
   into the measured azimuths (reduction 2 or 4), half vector, the VNDF warp inverted at it, RGB read at the warped
   point over the (phi_i, theta_i) slices (phi_vals: n_phi, theta_vals: n_theta), times ndf / (4 sigma) with the
   Jacobian, divided by cos(theta_o); 0 unless both directions are above the surface. out: n x 3. */
int rgl_eval(const float *wi, const float *wo, long n, int isotropic, int reduction, int jacobian,
             const float *phi_vals, int n_phi, const float *theta_vals, int n_theta, const Table2D *vndf,
             const Table2D *rgb, const Table2D *ndf, const Table2D *sigma, float *out) {
    const float two_over_pi = 0.6366197723675814f, pi = 3.141592653589793f, two_pi = 6.283185307179586f;
    const int one_slice = 0;
    const float one_weight = 1.f;
    for (long r = 0; r < n; ++r) {
        const float *a = wi + 3 * r, *b = wo + 3 * r;
        if (!(fminf(a[2], b[2]) > 0.f)) { out[3 * r] = out[3 * r + 1] = out[3 * r + 2] = 0.f; continue; }
        float i0 = a[0], i1 = a[1], i2 = a[2], o0 = b[0], o1 = b[1], o2 = b[2];
        if (reduction >= 2) {
            float sy = i1, sx = reduction == 4 ? i0 : sy;
            i0 = mulsign_neg(i0, sx); i1 = mulsign_neg(i1, sy); o0 = mulsign_neg(o0, sx); o1 = mulsign_neg(o1, sy);
        }
        float mx = i0 + o0, my = i1 + o1, mz = i2 + o2, ml = fmaxf(sqrtf(mx * mx + my * my + mz * mz), 1e-30f);
        mx /= ml; my /= ml; mz /= ml;
        float theta_i = elevation(i0, i1, i2), phi_i = fast_atan2(i1, i0);
        float theta_m = elevation(mx, my, mz), phi_m = fast_atan2(my, mx);
        float um0 = sqrtf(theta_m * two_over_pi), um1 = ((isotropic ? phi_m - phi_i : phi_m) + pi) / two_pi;
        um1 -= floorf(um1);
        float uw0 = sqrtf(theta_i * two_over_pi), uw1 = (phi_i + pi) / two_pi;
        /* the (phi_i, theta_i) slices, phi outermost (Marginal2D._slices' order) */
        int sl[4] = {0, 0, 0, 0}, count = 1;
        float w[4] = {1.f, 0.f, 0.f, 0.f};
        if (n_phi > 1) {
            int j; float t;
            grid_step(phi_vals, n_phi, phi_i, &j, &t);
            sl[0] = j * n_theta; sl[1] = (j + 1) * n_theta; w[0] = 1.f - t; w[1] = t; count = 2;
        }
        if (n_theta > 1) {
            int j; float t;
            grid_step(theta_vals, n_theta, theta_i, &j, &t);
            for (int c = 0; c < count; ++c) {
                sl[count + c] = sl[c] + j + 1; w[count + c] = w[c] * t;
                sl[c] += j; w[c] *= 1.f - t;
            }
            count *= 2;
        }
        float sx, sy, spec[3];
        table_invert(vndf, um0, um1, sl, w, count, &sx, &sy);
        table_eval(rgb, sx, sy, sl, w, count, spec);
        float scale = 1.f;
        if (jacobian) {
            float d = 0.f, sg = 1.f;  /* table_eval sets both (its tables have one channel) */
            table_eval(ndf, um0, um1, &one_slice, &one_weight, 1, &d);
            table_eval(sigma, uw0, uw1, &one_slice, &one_weight, 1, &sg);
            scale = d / (4.f * sg);
        }
        for (int c = 0; c < 3; ++c) out[3 * r + c] = jacobian ? spec[c] * scale / b[2] : spec[c] / b[2];
    }
    return 0;
}

/* NeuMIP on the object's spherical UV texture (neumat.methods.baselines.neumip_uv, NeuPreSS's baselines) of
   object-space wi, x, wo and unit normals nrm (n x 3 each): p = x - centre; uv = (atan2(p.y, p.x) / 2 pi + 0.5,
   acos(p.z / |p|) / pi); the frame t along (-p.y, p.x, 0) (+x at the poles) made orthogonal to nrm, b = nrm x t;
   z the bilinear read of the padded finest latent level (h + 2, w + 2, ds) at uv; the MLP on [z, wi, wo in the
   frame], clamped at 0, or with `surface` softplus of it times max(wi's local z, 0). out: n x out_dim. */
int neumip_uv_eval(const float *finest, int h, int w, int ds, const float *wi, const float *x, const float *wo,
                   const float *nrm, long n, const float *centre, int surface, int layers, const int *dims,
                   const float *const *W, const float *const *b, int hidden_act, int out_dim, float *out) {
    if (ds > 64 || ds + 6 > MAX_WIDTH) return 2;
    float *work = work_buffers();
    if (!work) return 1;
    float *buf0 = work, *buf1 = work + MAX_WIDTH * BLOCK, *rows = work + 2 * MAX_WIDTH * BLOCK;
    float uv[2 * BLOCK], lx[BLOCK], ly[BLOCK], lz[BLOCK];
    const float two_pi = 6.283185307179586f, pi = 3.141592653589793f;
    for (long s = 0; s < n; s += BLOCK) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        float *dirs = buf0 + ds * BLOCK;  /* wi, then wo in the frame, by component */
        for (int k = 0; k < BLOCK; ++k) {
            long row = s + (k < m ? k : 0);
            const float *q = x + 3 * row, *nn = nrm + 3 * row;
            float px = q[0] - centre[0], py = q[1] - centre[1], pz = q[2] - centre[2];
            float r = sqrtf(px * px + py * py + pz * pz);
            float cz = pz / (r > 1e-12f ? r : 1e-12f);
            uv[2 * k] = atan2f(py, px) / two_pi + 0.5f;
            uv[2 * k + 1] = acosf(cz < -1.f ? -1.f : (cz > 1.f ? 1.f : cz)) / pi;
            float tx = -py, ty = px, tz = 0.f;
            if (sqrtf(tx * tx + ty * ty) < 1e-6f * (r > 1e-12f ? r : 1e-12f)) { tx = 1.f; ty = 0.f; }
            float dot = tx * nn[0] + ty * nn[1] + tz * nn[2];
            tx -= dot * nn[0]; ty -= dot * nn[1]; tz -= dot * nn[2];
            float t2 = tx * tx + ty * ty + tz * tz, tl = sqrtf(t2 > 1e-24f ? t2 : 1e-24f);
            tx /= tl; ty /= tl; tz /= tl;
            float bx = nn[1] * tz - nn[2] * ty, by = nn[2] * tx - nn[0] * tz, bz = nn[0] * ty - nn[1] * tx;
            for (int e = 0; e < 2; ++e) {
                const float *v = (e ? wo : wi) + 3 * row;
                float *o = dirs + 3 * e * BLOCK;
                o[k] = v[0] * tx + v[1] * ty + v[2] * tz;
                o[BLOCK + k] = v[0] * bx + v[1] * by + v[2] * bz;
                o[2 * BLOCK + k] = v[0] * nn[0] + v[1] * nn[1] + v[2] * nn[2];
            }
        }
        latent_texels(uv, 0, BLOCK, h, w, lx, ly);
        for (int k = 0; k < BLOCK; ++k) latent_read(finest, h + 2, w + 2, ds, lx[k], ly[k], rows + k * ds);
        transpose_rows(rows, ds, buf0);
        memcpy(lz, dirs + 2 * BLOCK, sizeof lz);  /* wi's local z, for the surface form */
        const float *restrict y = mlp_block(buf0, buf1, layers, dims, W, b, hidden_act, m);
        for (int k = 0; k < m; ++k)
            for (int j = 0; j < out_dim; ++j) {
                float v = y[j * BLOCK + k];
                out[(s + k) * out_dim + j] = surface ? softplus(v) * (lz[k] > 0.f ? lz[k] : 0.f) : (v > 0.f ? v : 0.f);
            }
    }
    free(work);
    return 0;
}

/* sin and cos of a (|a| < 8192), branch-free (vectorisable): a reduced by multiples of pi / 2 in three parts (the
   first exact in float32 for such multiples, Cephes' split), then Taylor polynomials on [-pi / 4, pi / 4] (within
   about 1e-7 of sinf / cosf there), the quadrant picking sign and function */
static inline void fast_sincos(float a, float *s, float *c) {
    float k = rintf(a * 0.6366197723675814f);
    float r = ((a - k * 1.5703125f) - k * 4.837512969970703125e-4f) - k * 7.54978995489188216e-8f;
    float r2 = r * r;
    float sr = r + r * r2 * (-1.6666667163e-1f + r2 * (8.3333337680e-3f + r2 * (-1.9841270114e-4f
                                                                               + r2 * 2.7557314297e-6f)));
    float cr = 1.f + r2 * (-0.5f + r2 * (4.1666667908e-2f + r2 * (-1.3888889225e-3f + r2 * 2.4801587642e-5f)));
    int q = (int)k & 3;
    *s = q == 0 ? sr : (q == 1 ? cr : (q == 2 ? -sr : -cr));
    *c = q == 0 ? cr : (q == 1 ? -sr : (q == 2 ? -cr : sr));
}

/* y (out) = act(W x + b) for one row x (in), W (out x in) row-major: per output two 16-wide partial sums (a
   float sum the compiler may not reorder into vectors itself), then the rest one by one; relu or none */
static void matvec(const float *restrict W, const float *restrict b, const float *restrict x, float *restrict y,
                   int in, int out, int relu) {
    typedef float v16 __attribute__((vector_size(64), aligned(4)));
    for (int o = 0; o < out; ++o) {
        const float *w = W + (long)o * in;
        v16 s0 = {0}, s1 = {0};
        int i = 0;
        for (; i + 32 <= in; i += 32) {
            s0 += *(const v16 *)(w + i) * *(const v16 *)(x + i);
            s1 += *(const v16 *)(w + i + 16) * *(const v16 *)(x + i + 16);
        }
        s0 += s1;
        float acc = 0.f;
        for (int k = 0; k < 16; ++k) acc += s0[k];
        for (; i < in; ++i) acc += w[i] * x[i];
        acc += b[o];
        y[o] = relu && acc < 0.f ? 0.f : acc;
    }
}

/* NeuPreSS's appearance network (neumat.methods.neupress.model.NeuPreSS.eval) of object-space wi, x, wo (n x 3),
   one row at a time (for small batches: a call's cost is then its arithmetic, where torch pays each layer's
   dispatch; large batches are torch's sgemm): v = [wi, wo encoded (`spherical`: theta / pi, phi / 2 pi; else the
   vectors), (x - box_min) / box_size], the Fourier features [cos 2 pi G v, sin 2 pi G v] (Gt: G transposed, in_dim
   x F; fast_sincos, vectorised over the features), the skip MLP (first: width x 2F; `hidden` layers of width x
   width in pairs h <- relu(h + W2 relu(W1 h)) (with `skips`; else relu(W2 relu(W1 h))), an odd one left as relu(W
   h)), the linear output (3 x width), clamped at 0. out: n x 3. */
int neupress_rows(const float *wi, const float *x, const float *wo, long n, int spherical, const float *box_min,
                  const float *box_size, const float *Gt, int F, int in_dim, const float *W_first,
                  const float *b_first, int width, int hidden, const float *const *W, const float *const *b, int skips,
                  const float *W_out, const float *b_out, float *out) {
    const int d = spherical ? 2 : 3;
    if (in_dim != 2 * d + 3) return 2;
    float *buf = malloc(sizeof(float) * (2 * F + 3 * width + 16));
    if (!buf) return 1;
    float *feat = buf, *h = feat + 2 * F, *t1 = h + width, *t2 = t1 + width, v[16];
    const float pi = 3.14159265358979f, two_pi = 6.28318530717959f;
    for (long r = 0; r < n; ++r) {
        for (int e = 0; e < 2; ++e) {
            const float *w = (e ? wo : wi) + 3 * r;
            if (spherical) {  /* neumat.core.coords.dir_to_spherical */
                float z = w[2] < -1.f ? -1.f : (w[2] > 1.f ? 1.f : w[2]), phi = atan2f(w[1], w[0]);
                v[e * d] = acosf(z) / pi;
                v[e * d + 1] = (phi < 0.f ? phi + two_pi : phi) / two_pi;
            } else
                for (int j = 0; j < 3; ++j) v[e * d + j] = w[j];
        }
        for (int j = 0; j < 3; ++j) v[2 * d + j] = (x[3 * r + j] - box_min[j]) / box_size[j];
        for (int f = 0; f < F; ++f) feat[f] = 0.f;
        for (int j = 0; j < in_dim; ++j)
            for (int f = 0; f < F; ++f) feat[f] += v[j] * Gt[(long)j * F + f];
        for (int f = 0; f < F; ++f) fast_sincos(two_pi * feat[f], feat + F + f, feat + f);  /* vectorised */
        matvec(W_first, b_first, feat, h, 2 * F, width, 1);
        int l = 0;
        for (; l + 2 <= hidden; l += 2) {
            matvec(W[l], b[l], h, t1, width, width, 1);
            matvec(W[l + 1], b[l + 1], t1, t2, width, width, 0);
            for (int i = 0; i < width; ++i) {
                float u = skips ? h[i] + t2[i] : t2[i];
                h[i] = u > 0.f ? u : 0.f;
            }
        }
        if (l < hidden) {
            matvec(W[l], b[l], h, t1, width, width, 1);
            memcpy(h, t1, sizeof(float) * width);
        }
        matvec(W_out, b_out, h, t1, width, 3, 0);
        for (int j = 0; j < 3; ++j) out[3 * r + j] = t1[j] > 0.f ? t1[j] : 0.f;
    }
    free(buf);
    return 0;
}

/* the unpolarised reflectance of a dielectric interface (eta inside / outside) lit from outside at cos ci in [0, 1]
   (neumat.reflectance.microfacet.fresnel_dielectric; total internal reflection: 1) */
static inline float fresnel_outside(float ci, float eta) {
    float sin_t2 = (1.f - ci * ci) / (eta * eta);
    float ct = sqrtf(sin_t2 < 1.f ? 1.f - sin_t2 : 0.f);
    float rs = (ci - eta * ct) / (ci + eta * ct), rp = (eta * ci - ct) / (eta * ci + ct);
    return sin_t2 >= 1.f ? 1.f : 0.5f * (rs * rs + rp * rp);
}

/* The dipole BSSRDF (Jensen et al. 2001; neumat.methods.baselines.dipole_bssrdf.DipoleBSSRDF.raw) of object-space
   wi, x, wo and normals nrm at x (n x 3 each): out (n x 3) = (1 - F(n . wo)) [n . wo > 0] / pi times the sum over
   the K surface points p_k (normal n_k, area A_k) of (1 - F(max(wi . n_k, 0))) max(wi . n_k, 0) A_k R_d(|x - p_k|)
   per channel, F the unpolarised dielectric Fresnel reflectance at eta, R_d the dipole profile of sigma_a, sigma_s'
   (3 per query, or with `shared` 3 for all).
   Points and normals by component (3 x K: all x, then y, then z). The sum over points runs vectorised, one query
   at a time; its terms in float32 as torch computes them, summed in another order. */
int dipole_eval(const float *wi, const float *x, const float *wo, const float *nrm, long n, const float *sigma_a,
                const float *sigma_s, int shared, const float *points, const float *normals, const float *areas, int K,
                float eta, float f_dr, float *out) {
    const float *px = points, *py = points + K, *pz = points + 2 * K;
    const float *nx = normals, *ny = normals + K, *nz = normals + 2 * K;
    const float a = (1.f + f_dr) / (1.f - f_dr);
    for (long q = 0; q < n; ++q) {
        const float *w = wi + 3 * q, *c = x + 3 * q;
        const float *sa = sigma_a + (shared ? 0 : 3 * q), *ss = sigma_s + (shared ? 0 : 3 * q);
        float tr[3], zr[3], zv[3], scale[3];
        for (int ch = 0; ch < 3; ++ch) {
            const float st = sa[ch] + ss[ch];
            tr[ch] = sqrtf(3.f * sa[ch] * st);
            zr[ch] = 1.f / st;
            zv[ch] = zr[ch] * (1.f + 4.f * a / 3.f);
            scale[ch] = ss[ch] / st / (4.f * 3.14159265358979f);
        }
        float s0 = 0.f, s1 = 0.f, s2 = 0.f;
        for (int k = 0; k < K; ++k) {  /* vectorised */
            float cos = w[0] * nx[k] + w[1] * ny[k] + w[2] * nz[k];
            float ci = cos > 0.f ? (cos < 1.f ? cos : 1.f) : 0.f;
            float weight = ci > 0.f ? (1.f - fresnel_outside(ci, eta)) * ci * areas[k] : 0.f;
            float dx = c[0] - px[k], dy = c[1] - py[k], dz = c[2] - pz[k];
            float r2 = dx * dx + dy * dy + dz * dz;
            float prof[3];
            for (int ch = 0; ch < 3; ++ch) {
                float d2r = r2 + zr[ch] * zr[ch], d2v = r2 + zv[ch] * zv[ch];
                float dr = sqrtf(d2r), dv = sqrtf(d2v);
                float real = zr[ch] * (tr[ch] * dr + 1.f) * fast_exp(-tr[ch] * dr) / (d2r * dr);
                float virt = zv[ch] * (tr[ch] * dv + 1.f) * fast_exp(-tr[ch] * dv) / (d2v * dv);
                prof[ch] = real + virt;
            }
            s0 += weight * prof[0]; s1 += weight * prof[1]; s2 += weight * prof[2];
        }
        const float *v = wo + 3 * q, *m = nrm + 3 * q;
        float co = m[0] * v[0] + m[1] * v[1] + m[2] * v[2];
        float exit = co > 0.f ? (1.f - fresnel_outside(co < 1.f ? co : 1.f, eta)) / 3.14159265358979f : 0.f;
        out[3 * q] = s0 * scale[0] * exit; out[3 * q + 1] = s1 * scale[1] * exit; out[3 * q + 2] = s2 * scale[2] * exit;
    }
    return 0;
}

/* the k (<= 8) bins of dirs (3 x count: all x, then y, then z) nearest to w and their normalised
   inverse-angular-distance weights (neumat.reflectance.btf.angular_weights: the k largest dot products, the angle
   as atan2(|w x d|, w . d), an exact hit (angle <= 1e-7) weight 1 and the others 0); dots: count floats of work */
static void nearest_bins(const float *dirs, int count, const float *w, int k, int *idx, float *wt, float *dots) {
    const float *dx = dirs, *dy = dirs + count, *dz = dirs + 2 * count;
    for (int d = 0; d < count; ++d) dots[d] = w[0] * dx[d] + w[1] * dy[d] + w[2] * dz[d];  /* vectorised */
    float best[8];
    for (int a = 0; a < k; ++a) { best[a] = -INFINITY; idx[a] = 0; }
    for (int d = 0; d < count; ++d) {
        const float dot = dots[d];
        if (!(dot > best[k - 1])) continue;
        int a = k - 1;
        for (; a > 0 && dot > best[a - 1]; --a) { best[a] = best[a - 1]; idx[a] = idx[a - 1]; }
        best[a] = dot; idx[a] = d;
    }
    int exact = 0;
    float total = 0.f;
    for (int a = 0; a < k; ++a) {
        const float ex = dx[idx[a]], ey = dy[idx[a]], ez = dz[idx[a]];
        float cx = w[1] * ez - w[2] * ey, cy = w[2] * ex - w[0] * ez, cz = w[0] * ey - w[1] * ex;
        float angle = atan2f(sqrtf(cx * cx + cy * cy + cz * cz), w[0] * ex + w[1] * ey + w[2] * ez);
        exact |= angle <= 1e-7f;
        wt[a] = angle;
    }
    for (int a = 0; a < k; ++a) {
        wt[a] = exact ? (wt[a] <= 1e-7f ? 1.f : 0.f) : 1.f / (wt[a] > 1e-7f ? wt[a] : 1e-7f);
        total += wt[a];
    }
    for (int a = 0; a < k; ++a) wt[a] /= total;
}

/* the four wrap-around bilinear taps of uv in an h x w texture (neumat.reflectance.btf.bilinear_taps): rows,
   cols, weights; float32 step by step as there */
__attribute__((optimize("fp-contract=off")))
static void btf_taps(float u, float v, int h, int w, int *rows, int *cols, float *wt) {
    float x = u * (float)w - 0.5f, y = (1.f - v) * (float)h - 0.5f;
    float fx0 = floorf(x), fy0 = floorf(y), fx = x - fx0, fy = y - fy0;
    long x0 = (long)fx0, y0 = (long)fy0;
    long c0 = ((x0 % w) + w) % w, c1 = ((x0 + 1) % w + w) % w, r0 = ((y0 % h) + h) % h, r1 = ((y0 + 1) % h + h) % h;
    cols[0] = cols[2] = (int)c0; cols[1] = cols[3] = (int)c1;
    rows[0] = rows[1] = (int)r0; rows[2] = rows[3] = (int)r1;
    wt[0] = (1.f - fx) * (1.f - fy); wt[1] = fx * (1.f - fy); wt[2] = (1.f - fx) * fy; wt[3] = fx * fy;
}

/* A PCA-compressed BTF (neumat.methods.sparse_btf.pca.PCABTF, the SparseBTF paper's baseline) of directions wi, wo
   and uv (n x 3, n x 3, n x 2): for each of the four bilinear taps and each pair of the k nearest light and view
   bins, per channel c the dot product of the texel's coefficients (coeffs: 3 x texels x R) and the bin pair's
   basis row (basis: 3 x nl nv x R; a channel of fewer components has zeros past them), plus the pair's mean (3 x
   nl nv); YUV ->
   RGB (yuv_rgb, 3 x 3), exp minus eps, clamped at 0, weighted by tap x light x view weights and summed; 0 unless
   wi.z and wo.z > 0. Directions 3 x nl, 3 x nv. One query at a time. */
int pca_btf_eval(const float *wi, const float *wo, const float *uv, long n, const float *light_dirs, int nl,
                 const float *view_dirs, int nv, int k, int height, int width, int R, const float *coeffs,
                 const float *basis, const float *mean, const float *yuv_rgb, float eps, float *out) {
    if (k < 1 || k > 8) return 2;
    float *dots = malloc(sizeof(float) * (nl > nv ? nl : nv));
    if (!dots) return 1;
    const long texels = (long)height * width, bins = (long)nl * nv;
    for (long q = 0; q < n; ++q) {
        const float *a = wi + 3 * q, *b = wo + 3 * q;
        float *o = out + 3 * q;
        o[0] = o[1] = o[2] = 0.f;
        if (!(a[2] > 0.f && b[2] > 0.f)) continue;
        int li[8], vi[8], tr[4], tc[4];
        float lw[8], vw[8], tw[4];
        nearest_bins(light_dirs, nl, a, k, li, lw, dots);
        nearest_bins(view_dirs, nv, b, k, vi, vw, dots);
        btf_taps(uv[2 * q], uv[2 * q + 1], height, width, tr, tc, tw);
        float arg[3 * 4 * 64], wt[4 * 64];  /* per tap and bin pair: the exponents of R, G, B and the weight */
        int m = 0;
        for (int t = 0; t < 4; ++t) {
            const long texel = (long)tr[t] * width + tc[t];
            for (int s = 0; s < k; ++s)
                for (int e = 0; e < k; ++e, ++m) {
                    const long bin = (long)li[s] * nv + vi[e];
                    float yuv[3];
                    for (int c = 0; c < 3; ++c) {
                        const float *x = coeffs + ((long)c * texels + texel) * R, *y = basis + ((long)c * bins + bin) * R;
                        float acc = 0.f;
                        for (int j = 0; j < R; ++j) acc += x[j] * y[j];
                        yuv[c] = acc + mean[(long)c * bins + bin];
                    }
                    for (int c = 0; c < 3; ++c)
                        arg[c * 4 * 64 + m] = yuv_rgb[3 * c] * yuv[0] + yuv_rgb[3 * c + 1] * yuv[1]
                                              + yuv_rgb[3 * c + 2] * yuv[2];
                    wt[m] = tw[t] * lw[s] * vw[e];
                }
        }
        for (int c = 0; c < 3; ++c) {
            const float *x = arg + c * 4 * 64;
            float acc = 0.f;
            for (int i = 0; i < m; ++i) {  /* vectorised */
                float v = fast_exp(x[i]) - eps;
                acc += (v > 0.f ? v : 0.f) * wt[i];
            }
            o[c] = acc;
        }
    }
    free(dots);
    return 0;
}

/* A SparseBTF (Kavoosi et al.; neumat.methods.sparse_btf.model, angular interpolation in coefficient space) of
   directions wi, wo and uv (n x 3, n x 3, n x 2): per query its k nearest light and view bins, its four
   bilinear taps grouped by data point (patch), and per channel c and data point of dictionary m the sum over
   its count stored coefficients v_j of v_j S[i0, i1] r3[i2] r4[i3], S = sum over the point's taps of the tap
   weight times U1[m][x1] (x) U2[m][x2], r3 and r4 the bins' weighted rows of U3[m] and U4[m]; then times the
   bins' weighted std plus their weighted mean, YUV -> RGB (yuv_rgb, 3 x 3), exp minus eps, clamped at 0; 0
   unless wi.z and wo.z > 0. Tables (each channel outermost): membership, counts (P), values (P x T), index (P x
   T x 4), dict_1 / dict_2 (K x p x p), dict_3 (K x nl x nl), dict_4 (K x nv x nv); mean, std (nl x nv x 3); light_dirs, view_dirs: 3 x nl, 3 x nv.
   One query at a time. Returns 2 for sizes beyond its buffers. */
int sparse_btf_eval(const float *wi, const float *wo, const float *uv, long n, const float *light_dirs, int nl,
                    const float *view_dirs, int nv, int k, int height, int width, int p, int K, int T,
                    const int32_t *membership, const int32_t *counts, const float *values, const int32_t *index,
                    const float *dict_1, const float *dict_2, const float *dict_3, const float *dict_4,
                    const float *mean, const float *std, const float *yuv_rgb, float eps, float *out) {
    if (k < 1 || k > 8 || p > 32 || nl > 4096 || nv > 4096) return 2;
    const long patches = (long)(height / p) * (width / p);
    float *rows = malloc(sizeof(float) * 2 * (nl + nv));
    if (!rows) return 1;
    float *r3 = rows, *r4 = rows + nl, *dots = rows + nl + nv, S[32 * 32];
    for (long q = 0; q < n; ++q) {
        const float *a = wi + 3 * q, *b = wo + 3 * q;
        float *o = out + 3 * q;
        if (!(a[2] > 0.f && b[2] > 0.f)) { o[0] = o[1] = o[2] = 0.f; continue; }
        int li[8], vi[8], tr[4], tc[4], patch[4];
        float lw[8], vw[8], tw[4], yuv[3];
        nearest_bins(light_dirs, nl, a, k, li, lw, dots);
        nearest_bins(view_dirs, nv, b, k, vi, vw, dots);
        btf_taps(uv[2 * q], uv[2 * q + 1], height, width, tr, tc, tw);
        for (int t = 0; t < 4; ++t) patch[t] = (tr[t] / p) * (width / p) + tc[t] / p;
        for (int c = 0; c < 3; ++c) {
            float z = 0.f, mu = 0.f, sd = 0.f;
            for (int t = 0; t < 4; ++t) {
                int first = 0;
                while (patch[first] != patch[t]) ++first;
                if (first != t) continue;  /* a data point's taps are summed at its first */
                const long P = (long)c * patches + patch[t];
                const int m = membership[P];
                for (int e = 0; e < p * p; ++e) S[e] = 0.f;
                for (int u = t; u < 4; ++u) {
                    if (patch[u] != patch[t]) continue;
                    const float *u1 = dict_1 + (((long)c * K + m) * p + tr[u] % p) * p;
                    const float *u2 = dict_2 + (((long)c * K + m) * p + tc[u] % p) * p;
                    for (int i0 = 0; i0 < p; ++i0) {
                        const float f = tw[u] * u1[i0];
                        for (int i1 = 0; i1 < p; ++i1) S[i0 * p + i1] += f * u2[i1];
                    }
                }
                const float *d3 = dict_3 + ((long)c * K + m) * nl * nl, *d4 = dict_4 + ((long)c * K + m) * nv * nv;
                for (int e = 0; e < nl; ++e) r3[e] = 0.f;
                for (int e = 0; e < nv; ++e) r4[e] = 0.f;
                for (int s = 0; s < k; ++s) {
                    const float *row3 = d3 + (long)li[s] * nl, *row4 = d4 + (long)vi[s] * nv;
                    for (int e = 0; e < nl; ++e) r3[e] += lw[s] * row3[e];
                    for (int e = 0; e < nv; ++e) r4[e] += vw[s] * row4[e];
                }
                const float *val = values + P * T;
                const int32_t *ix = index + P * T * 4;
                for (int j = 0; j < counts[P]; ++j, ix += 4)
                    z += val[j] * S[ix[0] * p + ix[1]] * r3[ix[2]] * r4[ix[3]];
            }
            for (int s = 0; s < k; ++s)
                for (int e = 0; e < k; ++e) {
                    const long bin = ((long)li[s] * nv + vi[e]) * 3 + c;
                    const float w2 = lw[s] * vw[e];
                    mu += mean[bin] * w2;
                    sd += std[bin] * w2;
                }
            yuv[c] = z * sd + mu;
        }
        for (int c = 0; c < 3; ++c) {
            float v = expf(yuv_rgb[3 * c] * yuv[0] + yuv_rgb[3 * c + 1] * yuv[1] + yuv_rgb[3 * c + 2] * yuv[2]) - eps;
            o[c] = v > 0.f ? v : 0.f;
        }
    }
    free(rows);
    return 0;
}

/* A plain MLP on rows x (n x dims[0], row-major): out (n x out_dim), the last layer without activation. */
int mlp_forward(const float *x, long n, int layers, const int *dims, const float *const *W, const float *const *b,
                int hidden_act, int out_dim, float *out) {
    float *work = work_buffers();
    if (!work) return 1;
    float *buf0 = work, *buf1 = work + MAX_WIDTH * BLOCK;
    const int in = dims[0];
    for (long s = 0; s < n; s += BLOCK) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        for (int k = 0; k < BLOCK; ++k) {
            long r = s + (k < m ? k : 0);
            for (int i = 0; i < in; ++i) buf0[i * BLOCK + k] = x[in * r + i];
        }
        float *y = mlp_block(buf0, buf1, layers, dims, W, b, hidden_act, m);
        for (int k = 0; k < m; ++k)
            for (int c = 0; c < out_dim; ++c) out[out_dim * (s + k) + c] = y[c * BLOCK + k];
    }
    free(work);
    return 0;
}

/* ring_pixels of n unit vectors xyz (n x 3), `exact`: with atan2f on every row (tests) */
void ring_pixels_of(const float *xyz, long n, int nside, int exact, int32_t *pix) {
    float c[3 * BLOCK];
    int32_t p[BLOCK];
    for (long s = 0; s < n; s += BLOCK) {
        for (int k = 0; k < BLOCK; ++k)
            for (int j = 0; j < 3; ++j) c[j * BLOCK + k] = xyz[3 * (s + k < n ? s + k : s) + j];
        ring_pixels(c, c + BLOCK, c + 2 * BLOCK, nside, exact, p);
        for (int k = 0; k < BLOCK && s + k < n; ++k) pix[s + k] = p[k];
    }
}

/* HEALPix integer geometry, as neumat.nn.healpix computes it in int64 (bit-exact): floor division and remainder
   with the divisor's sign (torch's rounding_mode "floor" and remainder), exact integer square root */
static inline long floor_div(long a, long b) {
    const long q = a / b;
    return (a % b != 0 && ((a < 0) != (b < 0))) ? q - 1 : q;
}
static inline long floor_mod(long a, long b) {
    const long r = a % b;
    return (r != 0 && ((r < 0) != (b < 0))) ? r + b : r;
}
static inline long isqrt_l(long x) {
    long r = (long)sqrt((double)x);
    if (r * r > x) r -= 1;
    if ((r + 1) * (r + 1) <= x) r += 1;
    return r;
}
static const long HPX_JRLL[12] = {2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4};
static const long HPX_JPLL[12] = {1, 3, 5, 7, 0, 2, 4, 6, 1, 3, 5, 7};

/* face coordinates (ix, iy) and face of ring pixel pix (healpix._ring2xyf) */
static inline void hpx_ring2xyf(long n, long pix, long *ix, long *iy, long *face) {
    const long ncap = 2 * n * (n - 1), npix = 12 * n * n, nl2 = 2 * n;
    long iring, iphi, nr, kshift, f;
    if (pix < ncap) {
        const long ir = (1 + isqrt_l(1 + 2 * pix)) >> 1;
        iring = ir; iphi = pix + 1 - 2 * ir * (ir - 1); nr = ir; kshift = 0;
        f = floor_div(iphi - 1, ir > 1 ? ir : 1);
    } else if (pix >= npix - ncap) {
        const long ips = npix - pix > 1 ? npix - pix : 1, ir = (1 + isqrt_l(2 * ips - 1)) >> 1;
        iring = 2 * nl2 - ir; iphi = 4 * ir + 1 - (ips - 2 * ir * (ir - 1)); nr = ir; kshift = 0;
        f = floor_div(iphi - 1, ir > 1 ? ir : 1) + 8;
    } else {
        const long ip = pix - ncap, tmp = floor_div(ip, 4 * n), ire = tmp + 1, irm = nl2 + 1 - tmp;
        iring = tmp + n; iphi = ip - tmp * 4 * n + 1; nr = n; kshift = (iring + n) & 1;
        const long ifm = floor_div(iphi - (ire >> 1) + n - 1, n), ifp = floor_div(iphi - (irm >> 1) + n - 1, n);
        f = ifp == ifm ? (ifp | 4) : (ifp < ifm ? ifp : ifm + 8);
    }
    const long irt = iring - HPX_JRLL[f] * n + 1;
    long ipt = 2 * iphi - HPX_JPLL[f] * nr - kshift - 1;
    if (ipt >= 2 * nl2) ipt -= 8 * n;
    *ix = (ipt - irt) >> 1; *iy = (-ipt - irt) >> 1; *face = f;
}

/* the id of the first vertex on vertex ring r (healpix._ring_start) */
static inline long hpx_ring_start(long n, long r) {
    if (r == 0) return 0;
    const long s = 4 * n - r;
    if (r <= n) return 1 + 2 * r * (r - 1);
    return r >= 3 * n ? 12 * n * n + 1 - 2 * s * (s + 1) : 1 + 2 * n * (n - 1) + 4 * n * (r - n);
}

/* the vertex id of the face-coordinate point (x, y) in [0, n]^2 of face f (healpix._xyf2vertex) */
static inline long hpx_xyf2vertex(long n, long x, long y, long f) {
    const long r = HPX_JRLL[f] * n - x - y;
    const long nr = r < n ? r : (r > 3 * n ? 4 * n - r : n);
    const long t = HPX_JPLL[f] * nr + x - y, count = 4 * nr > 1 ? 4 * nr : 1;
    const long j = floor_mod(floor_div(floor_mod(t, 2 * count), 2), count);
    return hpx_ring_start(n, r) + (nr == 0 ? 0 : j);
}

/* the corner vertex ids (n x 4: north, west, south, east; healpix._corner_vertices) of the ancestors `level` steps up
   of ring pixels pix (n) at nside, level per pixel or, where NULL, `level_all` for every pixel, into vid (n x 4).
   Why: in torch these are some 60 int64 tensor operations a lookup, a sixth of a NeuBRDF training step. */
void healpix_corner_vertices(long nside, const int64_t *pix, const int64_t *level, int level_all, long n,
                             int64_t *vid) {
    for (long i = 0; i < n; ++i) {
        long ix, iy, f;
        hpx_ring2xyf(nside, pix[i], &ix, &iy, &f);
        const long l = level ? level[i] : level_all, x0 = (ix >> l) << l, y0 = (iy >> l) << l, s = 1L << l;
        vid[4 * i] = hpx_xyf2vertex(nside, x0 + s, y0 + s, f);
        vid[4 * i + 1] = hpx_xyf2vertex(nside, x0, y0 + s, f);
        vid[4 * i + 2] = hpx_xyf2vertex(nside, x0, y0, f);
        vid[4 * i + 3] = hpx_xyf2vertex(nside, x0 + s, y0, f);
    }
}

/* The kernels' own exp / expm1 on n floats (for tests against float64). */
void exp_values(const float *x, long n, int minus_one, float *out) {
    for (long i = 0; i < n; ++i) out[i] = minus_one ? fast_expm1(x[i]) : fast_exp(x[i]);
}
