/* Fused CPU kernels of small-MLP evaluations (neumat.nn.cpu_kernels compiles this file at first use).

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

enum { ACT_NONE = 0, ACT_RELU = 1, ACT_LEAKY_RELU = 2 };

/* the slope below 0 of an activation: max(v, 0) is v >= 0 ? v : 0 v, leaky ReLU's 0.01 v, none's v */
static inline float negative_slope(int kind) {
    return kind == ACT_RELU ? 0.f : (kind == ACT_LEAKY_RELU ? 0.01f : 1.f);
}

/* y[o][k] = act(sum_i W[o][i] x[i][k] + b[o]) for o < out (a multiple of 4), k < BLOCK: 4 outputs at a time,
   their 4 x BLOCK sums held in vector registers (GCC / Clang vector extensions, split by the compiler to the
   machine's SIMD width) while the inputs stream past. x and y are 64-byte aligned. */
typedef float vec __attribute__((vector_size(64)));
#define VLEN 16
#define NV (BLOCK / VLEN)

static void dense(const float *restrict W, const float *restrict b, const float *restrict x, float *restrict y,
                  int in, int out, int kind) {
    const float slope = negative_slope(kind);
    for (int o = 0; o < out; o += 4) {
        vec a0[NV], a1[NV], a2[NV], a3[NV];
        for (int v = 0; v < NV; ++v) {
            a0[v] = (vec){} + b[o]; a1[v] = (vec){} + b[o + 1]; a2[v] = (vec){} + b[o + 2]; a3[v] = (vec){} + b[o + 3];
        }
        const float *w0 = W + (long)o * in, *w1 = w0 + in, *w2 = w1 + in, *w3 = w2 + in;
        for (int i = 0; i < in; ++i) {
            const vec *xi = (const vec *)(x + i * BLOCK);
            const float c0 = w0[i], c1 = w1[i], c2 = w2[i], c3 = w3[i];
            for (int v = 0; v < NV; ++v) {
                a0[v] += c0 * xi[v]; a1[v] += c1 * xi[v]; a2[v] += c2 * xi[v]; a3[v] += c3 * xi[v];
            }
        }
        vec *yo = (vec *)(y + o * BLOCK);
        for (int v = 0; v < NV; ++v) {
            yo[v] = a0[v]; yo[NV + v] = a1[v]; yo[2 * NV + v] = a2[v]; yo[3 * NV + v] = a3[v];
        }
        float *yf = y + o * BLOCK;
        for (int k = 0; k < 4 * BLOCK; ++k) yf[k] = yf[k] >= 0.f ? yf[k] : slope * yf[k];
    }
}

/* a call's block buffers, on the heap (192 KB: more than some threads' stacks hold); NULL when out of memory */
static float *work_buffers(void) {
    return aligned_alloc(64, 3 * sizeof(float) * MAX_WIDTH * BLOCK);
}

/* the MLP on one transposed block: x (dims[0] x BLOCK) in buf0; returns the buffer holding the output */
static float *mlp_block(float *buf0, float *buf1, int layers, const int *dims, const float *const *W,
                        const float *const *b, int hidden_act) {
    float *x = buf0, *y = buf1;
    for (int l = 0; l < layers; ++l) {
        dense(W[l], b[l], x, y, dims[l], dims[l + 1], l < layers - 1 ? hidden_act : ACT_NONE);
        float *t = x; x = y; y = t;
    }
    return x;
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

/* NBRDF (Sztrajman et al. 2021) of directions wi, wo (n x 3, float32): h = normalize(wi + wo), d = wi in the
   frame (t, b, h) of neumat.core.coords.hd_vectors; half_theta: h -> (sin theta_h, 0, cos theta_h); fold: d ->
   (-dx, -dy, dz) where dy < 0; the MLP; then max(expm1(y), 0) (exp_minus_one) or exp(y); 0 where wi.z or wo.z
   <= 0. out: n x out_dim. */
int nbrdf_eval(const float *wi, const float *wo, long n, int layers, const int *dims, const float *const *W,
               const float *const *b, int hidden_act, int half_theta, int fold, int exp_minus_one, int out_dim,
               float *out) {
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
            float ix = pi[3 * k], iy = pi[3 * k + 1], iz = pi[3 * k + 2];
            float hx = ix + po[3 * k], hy = iy + po[3 * k + 1], hz = iz + po[3 * k + 2];
            float norm = sqrtf(hx * hx + hy * hy + hz * hz);
            norm = norm > 1e-12f ? norm : 1e-12f;
            hx /= norm; hy /= norm; hz /= norm;
            float st = sqrtf(hx * hx + hy * hy);
            float sd = st > 1.17549435e-38f ? st : 1.17549435e-38f;
            float ux = st > 0.f ? hx / sd : 1.f, uy = st > 0.f ? hy / sd : 0.f;
            float tx = hz * ux, ty = hz * uy, tz = -st;
            float bx = hy * tz - hz * ty, by = hz * tx - hx * tz, bz = hx * ty - hy * tx;
            float dx = tx * ix + ty * iy + tz * iz, dy = bx * ix + by * iy + bz * iz, dz = hx * ix + hy * iy + hz * iz;
            float flip = fold && dy < 0.f ? -1.f : 1.f;
            buf0[k] = half_theta ? st : hx;
            buf0[BLOCK + k] = half_theta ? 0.f : hy;
            buf0[2 * BLOCK + k] = hz;
            buf0[3 * BLOCK + k] = flip * dx; buf0[4 * BLOCK + k] = flip * dy; buf0[5 * BLOCK + k] = dz;
            res[out_dim * BLOCK + k] = iz > 0.f && po[3 * k + 2] > 0.f ? 1.f : 0.f;  /* above the horizon */
        }
        const float *restrict y = mlp_block(buf0, buf1, layers, dims, W, b, hidden_act);
        if (exp_minus_one)
            for (int i = 0; i < out_dim * BLOCK; ++i) {
                float v = fast_expm1(y[i]);
                res[i] = v > 0.f ? v : 0.f;
            }
        else
            for (int i = 0; i < out_dim * BLOCK; ++i) res[i] = fast_exp(y[i]);
        for (int k = 0; k < m; ++k)
            for (int c = 0; c < out_dim; ++c)
                out[out_dim * (s + k) + c] = res[out_dim * BLOCK + k] > 0.f ? res[c * BLOCK + k] : 0.f;
    }
    free(work);
    return 0;
}

/* HEALPix ring pixel of unit vectors (x, y, z) (BLOCK each), float32 step by step as neumat.nn.healpix.vec2pix_xyz
   (healpy's loc2pix; each product and sum rounded on its own: no fused multiply-adds here, so that a direction
   falls in the pixel the torch path finds; atan2 may still differ by an ulp from torch's at a pixel edge). */
__attribute__((optimize("fp-contract=off"), noinline))
static void ring_pixels(const float *x, const float *y, const float *z, int nside, int32_t *pix) {
    const float nf = (float)nside, half_n = 0.5f * (float)nside, three_quarter_n = 0.75f * (float)nside;
    const float two_over_pi = (float)(2.0 / 3.14159265358979323846), third = (float)(1.0 / 3.0);
    const float two_thirds = (float)(2.0 / 3.0);
    const int32_t ncap_4n2 = 2 * nside * (nside - 1) + 4 * nside * nside, npix = 12 * nside * nside;
    for (int k = 0; k < BLOCK; ++k) {
        float tt = atan2f(y[k], x[k]) * two_over_pi;
        tt = tt < 0.f ? tt + 4.f : tt;       /* torch.remainder(tt, 4) for tt in (-2, 2] */
        tt = tt >= 4.f ? 0.f : tt;
        float za = fabsf(z[k]);
        float temp1 = tt * nf + half_n, temp2 = z[k] * three_quarter_n;
        int32_t jp = (int32_t)(temp1 - temp2), jm = (int32_t)(temp1 + temp2);
        int32_t e = (jp + jm + 1 - nside) >> 1, m4 = 4 * nside;
        e %= m4;
        e = e < 0 ? e + m4 : e;
        int32_t pix_eq = e + 4 * nside * (jp - jm) + ncap_4n2;
        float tp = tt - truncf(tt);
        float sth = sqrtf(x[k] * x[k] + y[k] * y[k]);
        float tmp = sth * nf / sqrtf((za + 1.f) * third);
        int32_t cp = (int32_t)(tp * tmp), cm = (int32_t)((1.f - tp) * tmp);
        int32_t ir = cp + cm + 1;
        int32_t ip = (int32_t)(tt * (float)ir);
        ip = ip < 4 * ir - 1 ? ip : 4 * ir - 1;
        ip -= 2 * ir;
        int32_t pix_cap = z[k] > 0.f ? ip + 2 * ir * ir : ip - 2 * ir * ir + npix;
        pix[k] = za <= two_thirds ? pix_eq : pix_cap;
    }
}

/* NeuBRDF's runtime form (Dou, Zheng et al. 2024; neumat.methods.neubrdf.model, uniform corner weights, no
   direction inputs) of directions wi, wo (n x 3, float32): the first layer's pre-activations as the sum of the
   table rows of wi's ring pixel and of wo's (offset by 12 nside^2: the S- half), `first_act`, the MLP's other
   layers, exp; 0 where wi.z or wo.z <= 0. table: (24 nside^2) x hidden. out: n x out_dim. */
/* the ring pixels of a block's wi and wo (rows s .. s + BLOCK - 1; past n, row s again), whether each row is above
   the horizon, and a prefetch of the table rows they will read (the table is far larger than the caches) */
static void block_pixels(const float *wi, const float *wo, long s, long n, int nside, const float *table, int hidden,
                         int32_t *pix_i, int32_t *pix_o, float *up) {
    float c[6 * BLOCK];
    const long south = 12L * nside * nside;
    for (int k = 0; k < BLOCK; ++k) {
        long r = s + k < n ? s + k : s;
        for (int j = 0; j < 3; ++j) { c[j * BLOCK + k] = wi[3 * r + j]; c[(3 + j) * BLOCK + k] = wo[3 * r + j]; }
        up[k] = wi[3 * r + 2] > 0.f && wo[3 * r + 2] > 0.f ? 1.f : 0.f;
    }
    ring_pixels(c, c + BLOCK, c + 2 * BLOCK, nside, pix_i);
    ring_pixels(c + 3 * BLOCK, c + 4 * BLOCK, c + 5 * BLOCK, nside, pix_o);
    for (int k = 0; k < BLOCK; ++k) {
        const char *ti = (const char *)(table + (long)pix_i[k] * hidden);
        const char *to = (const char *)(table + (south + pix_o[k]) * hidden);
        for (long byte = 0; byte < (long)hidden * 4; byte += 64) {
            __builtin_prefetch(ti + byte);
            __builtin_prefetch(to + byte);
        }
    }
}

int neubrdf_eval(const float *wi, const float *wo, long n, int nside, const float *table, int hidden,
                 int first_act, int layers, const int *dims, const float *const *W, const float *const *b,
                 int hidden_act, int out_dim, float *out) {
    float *work = work_buffers();
    if (!work) return 1;
    float *buf0 = work, *buf1 = work + MAX_WIDTH * BLOCK, *res = work + 2 * MAX_WIDTH * BLOCK, up[2][BLOCK];
    int32_t pix_i[2][BLOCK], pix_o[2][BLOCK];
    const float slope = negative_slope(first_act);
    const long south = 12L * nside * nside;
    if (n > 0) block_pixels(wi, wo, 0, n, nside, table, hidden, pix_i[0], pix_o[0], up[0]);
    for (long s = 0, cur = 0; s < n; s += BLOCK, cur ^= 1) {
        int m = n - s < BLOCK ? (int)(n - s) : BLOCK;
        if (s + BLOCK < n)  /* the next block's rows are fetched while this one runs its MLP */
            block_pixels(wi, wo, s + BLOCK, n, nside, table, hidden, pix_i[cur ^ 1], pix_o[cur ^ 1], up[cur ^ 1]);
        for (int k = 0; k < BLOCK; ++k) {
            const float *ti = table + (long)pix_i[cur][k] * hidden, *to = table + (south + pix_o[cur][k]) * hidden;
            for (int i = 0; i < hidden; ++i) {
                float v = ti[i] + to[i];
                buf0[i * BLOCK + k] = v >= 0.f ? v : slope * v;
            }
        }
        const float *restrict y = mlp_block(buf0, buf1, layers, dims, W, b, hidden_act);
        for (int i = 0; i < out_dim * BLOCK; ++i) res[i] = fast_exp(y[i]);
        for (int k = 0; k < m; ++k)
            for (int j = 0; j < out_dim; ++j)
                out[out_dim * (s + k) + j] = up[cur][k] > 0.f ? res[j * BLOCK + k] : 0.f;
    }
    free(work);
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
        float *y = mlp_block(buf0, buf1, layers, dims, W, b, hidden_act);
        for (int k = 0; k < m; ++k)
            for (int c = 0; c < out_dim; ++c) out[out_dim * (s + k) + c] = y[c * BLOCK + k];
    }
    free(work);
    return 0;
}

/* ring_pixels of n unit vectors xyz (n x 3) (tests against neumat.nn.healpix.vec2pix_xyz) */
void ring_pixels_of(const float *xyz, long n, int nside, int32_t *pix) {
    float c[3 * BLOCK];
    int32_t p[BLOCK];
    for (long s = 0; s < n; s += BLOCK) {
        for (int k = 0; k < BLOCK; ++k)
            for (int j = 0; j < 3; ++j) c[j * BLOCK + k] = xyz[3 * (s + k < n ? s + k : s) + j];
        ring_pixels(c, c + BLOCK, c + 2 * BLOCK, nside, p);
        for (int k = 0; k < BLOCK && s + k < n; ++k) pix[s + k] = p[k];
    }
}

/* The kernels' own exp / expm1 on n floats (for tests against float64). */
void exp_values(const float *x, long n, int minus_one, float *out) {
    for (long i = 0; i < n; ++i) out[i] = minus_one ? fast_expm1(x[i]) : fast_exp(x[i]);
}
