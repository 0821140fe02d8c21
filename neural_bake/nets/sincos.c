/* sin and cos of float32 arrays in one pass: the fused kernel of neural_bake.nets.fastmath.

   One Cody-Waite reduction x = k·π/2 + r, |r| ≤ π/4 (π/2 split in three parts, exact for |k| < 2^16), then
   Cephes' minimax polynomials for sin r and cos r on [-π/4, π/4] and the quadrant k mod 4 picks and signs
   them. Max error ~1e-7 absolute (≤ 2 ulp of 1), against 4e-8 for torch.sin. Blocks holding a value with
   |x| > 65536, an infinity or a NaN take libm's sinf/cosf instead (same results as torch: NaN for inf/NaN).
   The polynomial loop has no branches, so compilers vectorise it (AVX-512: 16 lanes, AVX2: 8; each clone gives
   the same bits, as FMA contraction is off).

   nb_sincos_f32(a, s, c, n): s[i] = sin a[i], c[i] = cos a[i]; c may be a (cos written in place).
   nb_sin_f32(a, s, n): s[i] = sin a[i]; s may be a (in place). The same reduction and polynomials.
   nb_sincos_f32_mt(a, s, c, n, threads), nb_sin_f32_mt(a, s, n, threads): the same split over an OpenMP team of
   `threads` in pieces of whole blocks (so each block, and each value, is computed as on one thread); on the
   calling thread where built without OpenMP or for fewer than two pieces. */
#include <math.h>
#include <stdint.h>
#include <string.h>

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 11
#define NB_TARGETS __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#elif defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define NB_TARGETS __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define NB_TARGETS
#endif

#define NB_BLOCK 256

/* the reduction and both polynomials for |x| <= 65536: sin r, cos r and the quadrant k */
static inline int32_t nb_reduce(float x, float *sp, float *cp) {
    float k = rintf(x * 0.636619772367581343f);
    float r = x - k * 1.5703125f;
    r = r - k * 4.837512969970703125e-4f;
    r = r - k * 7.54978995489188216e-8f;
    float z = r * r;
    *sp = r + r * z * (-1.6666654611e-1f + z * (8.3321608736e-3f + z * -1.9515295891e-4f));
    *cp = 1.0f - 0.5f * z
          + z * z * (4.166664568298827e-2f + z * (-1.388731625493765e-3f + z * 2.443315711809948e-5f));
    return (int32_t)k;
}

/* sin of quadrant q: the polynomial q's parity picks and the sign q's second bit gives, by bit masks so that
   the loops stay branch-free and vectorise (with plain selects and the cosine unused, GCC emitted branches
   and the sin-only loop ran 13x slower); cos x is the pick of quadrant q + 1 */
static inline float nb_pick(float sp, float cp, int32_t q) {
    uint32_t sb, cb;
    memcpy(&sb, &sp, 4);
    memcpy(&cb, &cp, 4);
    uint32_t odd = -(uint32_t)(q & 1);
    uint32_t v = ((cb & odd) | (sb & ~odd)) ^ ((uint32_t)(q & 2) << 30);
    float out;
    memcpy(&out, &v, 4);
    return out;
}

/* copies a block into xb; nonzero when it holds |x| > 65536, an infinity or a NaN */
static inline int nb_load(const float *a, float *xb, int64_t m) {
    int wild = 0;
    for (int64_t j = 0; j < m; j++) {
        float x = a[j];
        xb[j] = x;
        wild |= !(fabsf(x) <= 65536.0f); /* also true for NaN */
    }
    return wild;
}

NB_TARGETS
void nb_sin_f32(const float *a, float *s, int64_t n) {
    float xb[NB_BLOCK];
    for (int64_t i0 = 0; i0 < n; i0 += NB_BLOCK) {
        int64_t m = (n - i0) < NB_BLOCK ? (n - i0) : NB_BLOCK;
        int wild = nb_load(a + i0, xb, m);
        float *restrict sb = s + i0;
        if (wild) {
            for (int64_t j = 0; j < m; j++) sb[j] = sinf(xb[j]);
            continue;
        }
        for (int64_t j = 0; j < m; j++) {
            float sp, cp;
            int32_t q = nb_reduce(xb[j], &sp, &cp);
            sb[j] = nb_pick(sp, cp, q);
        }
    }
}

NB_TARGETS
void nb_sincos_f32(const float *a, float *s, float *c, int64_t n) {
    float xb[NB_BLOCK];
    for (int64_t i0 = 0; i0 < n; i0 += NB_BLOCK) {
        int64_t m = (n - i0) < NB_BLOCK ? (n - i0) : NB_BLOCK;
        int wild = nb_load(a + i0, xb, m);
        float *restrict sb = s + i0;
        float *restrict cb = c + i0;
        if (wild) {
            for (int64_t j = 0; j < m; j++) {
                sb[j] = sinf(xb[j]);
                cb[j] = cosf(xb[j]);
            }
            continue;
        }
        for (int64_t j = 0; j < m; j++) {
            float sp, cp;
            int32_t q = nb_reduce(xb[j], &sp, &cp);
            sb[j] = nb_pick(sp, cp, q);
            cb[j] = nb_pick(sp, cp, q + 1);
        }
    }
}

/* values a piece of the threaded entries holds: whole blocks, large enough to pay for a team's wake-up */
#define NB_PIECE (64 * NB_BLOCK)

/* sin (c NULL) or sin and cos of a over a team of `threads`, piece by piece */
static void nb_split(const float *a, float *s, float *c, int64_t n, int64_t threads) {
    const int64_t pieces = (n + NB_PIECE - 1) / NB_PIECE;
    const int team = threads >= 2 && pieces >= 2;
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(team ? (int)threads : 1) if(team)
#endif
    for (int64_t p = 0; p < pieces; p++) {
        const int64_t i0 = p * NB_PIECE, m = (n - i0) < NB_PIECE ? (n - i0) : NB_PIECE;
        if (c != NULL)
            nb_sincos_f32(a + i0, s + i0, c + i0, m);
        else
            nb_sin_f32(a + i0, s + i0, m);
    }
    (void)team;
}

void nb_sincos_f32_mt(const float *a, float *s, float *c, int64_t n, int64_t threads) {
    nb_split(a, s, c, n, threads);
}

void nb_sin_f32_mt(const float *a, float *s, int64_t n, int64_t threads) { nb_split(a, s, NULL, n, threads); }
