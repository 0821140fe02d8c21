/* Edge padding of UV charts: the C kernels of neural_bake.bake.padding (its torch and numpy paths are the
   references; the tests hold the pull-push within a few ulps of torch's and the dilation bit for bit equal to
   numpy's).

   nb_pull_push_T(img, covered, h, w, c, work, out, threads): img (h, w, c) row-major, covered (h, w) uint8;
   out (h, w, c) gets the pushed-down values of the pyramid of coverage-weighted 2×2 averages at every texel not
   covered, img's own at the covered ones. work: scratch of nb_pull_push_work(h, w, c) elements. The same arithmetic as
   the torch path: each level pads an odd side with zero weight, sums 2×2 blocks, holds averages with weight
   min(1, sum); the push upsamples ×2 bilinearly (texel centres aligned, borders replicated) and blends each
   level's own average in by its weight. Each level's rows are split over an OpenMP team of `threads` where
   built with OpenMP (every texel is computed as on one thread).

   nb_dilate_T(out, filled, h, w, c, steps, threads): steps rings of dilation in place: each ring gives the
   unfilled texels next to a filled one the mean of their filled 8-neighbours (texels filled before the ring only,
   in the neighbour order of the numpy path, accumulated in T); filled (h, w) uint8 (0/1) is updated. The first
   ring's rows over a team of `threads` where built with OpenMP (each texel computed as on one thread). Returns 0
   (and changes nothing) when its scratch cannot be allocated or c > 64. */
#include <stdint.h>
#include <stdlib.h>

static int64_t nb_levels(int64_t h, int64_t w, int64_t *hs, int64_t *ws) {
    int64_t n = 0;
    hs[0] = h;
    ws[0] = w;
    while ((hs[n] > 1 || ws[n] > 1) && n < 62) {
        hs[n + 1] = (hs[n] + 1) / 2;
        ws[n + 1] = (ws[n] + 1) / 2;
        n++;
    }
    return n + 1;
}

int64_t nb_pull_push_work(int64_t h, int64_t w, int64_t c) {
    int64_t hs[64], ws[64];
    int64_t n = nb_levels(h, w, hs, ws), total = 0;
    for (int64_t i = 1; i < n; i++) total += hs[i] * ws[i] * (c + 1);
    return total;
}

/* a level's rows over the team, where the level holds enough values to pay for its wake-up */
#ifdef _OPENMP
#define NB_ROWS _Pragma("omp parallel for schedule(static) num_threads(nt) if(big)")
#else
#define NB_ROWS
#endif
#define NB_ROWS_MIN 32768

static const int NB_DI[8] = {-1, -1, -1, 0, 0, 1, 1, 1};
static const int NB_DJ[8] = {-1, 0, 1, -1, 1, -1, 0, 1};

#define NB_PADDING(T, SUFFIX)                                                                                  \
    void nb_pull_push_##SUFFIX(const T *img, const uint8_t *covered, int64_t h, int64_t w, int64_t c, T *work, \
                               T *out, int64_t threads) {                                                      \
        int64_t hs[64], ws[64];                                                                                \
        const int nt = threads > 1 ? (int)threads : 1;                                                         \
        int64_t n = nb_levels(h, w, hs, ws);                                                                   \
        T *cl[64], *wl[64];                                                                                    \
        T *p = work;                                                                                           \
        for (int64_t i = 1; i < n; i++) {                                                                      \
            cl[i] = p;                                                                                         \
            p += hs[i] * ws[i] * c;                                                                            \
            wl[i] = p;                                                                                         \
            p += hs[i] * ws[i];                                                                                \
        }                                                                                                      \
        if (n == 1) { /* a single texel: its own value where covered */                                       \
            for (int64_t k = 0; k < c; k++) out[k] = covered[0] ? img[k] : (T)0;                               \
            return;                                                                                            \
        }                                                                                                      \
        /* pull */                                                                                             \
        for (int64_t i = 1; i < n; i++) {                                                                      \
            int64_t ph = hs[i - 1], pw = ws[i - 1];                                                            \
            const int big = nt > 1 && hs[i] * ws[i] * (c + 1) >= NB_ROWS_MIN;                                  \
            NB_ROWS                                                                                            \
            for (int64_t y = 0; y < hs[i]; y++) {                                                              \
                for (int64_t x = 0; x < ws[i]; x++) {                                                          \
                    T *cv = cl[i] + (y * ws[i] + x) * c;                                                       \
                    T sw = 0;                                                                                  \
                    int64_t k;                                                                                 \
                    for (int64_t k2 = 0; k2 < c; k2++) cv[k2] = 0;                                             \
                    for (int dy = 0; dy < 2; dy++) {                                                           \
                        int64_t yy = 2 * y + dy;                                                               \
                        if (yy >= ph) continue;                                                                \
                        for (int dx = 0; dx < 2; dx++) {                                                       \
                            int64_t xx = 2 * x + dx;                                                           \
                            if (xx >= pw) continue;                                                            \
                            int64_t q = yy * pw + xx;                                                          \
                            if (i == 1) {                                                                      \
                                T wt = covered[q] ? (T)1 : (T)0;                                               \
                                sw += wt;                                                                      \
                                for (k = 0; k < c; k++) cv[k] += img[q * c + k] * wt;                          \
                            } else {                                                                           \
                                sw += wl[i - 1][q];                                                            \
                                for (k = 0; k < c; k++) cv[k] += cl[i - 1][q * c + k];                         \
                            }                                                                                  \
                        }                                                                                      \
                    }                                                                                          \
                    T wn = sw < (T)1 ? sw : (T)1;                                                              \
                    T d = sw > (T)1e-30 ? sw : (T)1e-30;                                                       \
                    for (k = 0; k < c; k++) cv[k] = cv[k] / d * wn;                                            \
                    wl[i][y * ws[i] + x] = wn;                                                                 \
                }                                                                                              \
            }                                                                                                  \
        }                                                                                                      \
        /* the coarsest level's averages */                                                                    \
        {                                                                                                      \
            int64_t i = n - 1;                                                                                 \
            for (int64_t q = 0; q < hs[i] * ws[i]; q++) {                                                      \
                T d = wl[i][q] > (T)1e-30 ? wl[i][q] : (T)1e-30;                                               \
                for (int64_t k = 0; k < c; k++) cl[i][q * c + k] /= d;                                         \
            }                                                                                                  \
        }                                                                                                      \
        /* push: level i's values from level i + 1's, upsampled, blended with its own average */              \
        for (int64_t i = n - 2; i >= 0; i--) {                                                                 \
            int64_t hh = hs[i + 1], ww = ws[i + 1];                                                            \
            const T *src = cl[i + 1];                                                                          \
            T *dst = i == 0 ? out : cl[i];                                                                     \
            const int big = nt > 1 && hs[i] * ws[i] * (c + 1) >= NB_ROWS_MIN;                                  \
            NB_ROWS                                                                                            \
            for (int64_t y = 0; y < hs[i]; y++) {                                                              \
                T sy = ((T)y + (T)0.5) * (T)0.5 - (T)0.5;                                                      \
                if (sy < 0) sy = 0;                                                                            \
                int64_t y0 = (int64_t)sy, y1 = y0 + (y0 < hh - 1);                                             \
                T ly1 = sy - (T)y0, ly0 = (T)1 - ly1;                                                          \
                for (int64_t x = 0; x < ws[i]; x++) {                                                          \
                    T sx = ((T)x + (T)0.5) * (T)0.5 - (T)0.5;                                                  \
                    if (sx < 0) sx = 0;                                                                        \
                    int64_t x0 = (int64_t)sx, x1 = x0 + (x0 < ww - 1);                                         \
                    T lx1 = sx - (T)x0, lx0 = (T)1 - lx1;                                                      \
                    const T *a = src + (y0 * ww + x0) * c, *b = src + (y0 * ww + x1) * c;                      \
                    const T *e = src + (y1 * ww + x0) * c, *f = src + (y1 * ww + x1) * c;                      \
                    T *o = dst + (y * ws[i] + x) * c;                                                          \
                    T wt = i == 0 ? (T)0 : wl[i][y * ws[i] + x];                                               \
                    T d = wt > (T)1e-30 ? wt : (T)1e-30;                                                       \
                    T al = wt < (T)0 ? (T)0 : (wt > (T)1 ? (T)1 : wt);                                         \
                    for (int64_t k = 0; k < c; k++) {                                                          \
                        T up = ly0 * (lx0 * a[k] + lx1 * b[k]) + ly1 * (lx0 * e[k] + lx1 * f[k]);             \
                        if (i == 0) {                                                                          \
                            o[k] = covered[y * ws[0] + x] ? img[(y * ws[0] + x) * c + k] : up;                 \
                        } else {                                                                               \
                            T own = o[k] / d;                                                                  \
                            o[k] = up + al * (own - up);                                                       \
                        }                                                                                      \
                    }                                                                                          \
                }                                                                                              \
            }                                                                                                  \
        }                                                                                                      \
    }                                                                                                          \
                                                                                                               \
    static int nb_fill_##SUFFIX(T *out, const uint8_t *filled, int64_t h, int64_t w, int64_t c, int64_t q) {  \
        T acc[64], cnt = 0;                                                                                    \
        int64_t y = q / w, x = q % w;                                                                          \
        for (int64_t k = 0; k < c; k++) acc[k] = 0;                                                            \
        for (int j = 0; j < 8; j++) {                                                                          \
            int64_t ny = y + NB_DI[j], nx = x + NB_DJ[j];                                                      \
            if (ny < 0 || ny >= h || nx < 0 || nx >= w) continue;                                              \
            int64_t r = ny * w + nx;                                                                           \
            if (filled[r] != 1) continue;                                                                      \
            for (int64_t k = 0; k < c; k++) acc[k] += out[r * c + k];                                          \
            cnt += 1;                                                                                          \
        }                                                                                                      \
        if (cnt == 0) return 0;                                                                                \
        for (int64_t k = 0; k < c; k++) out[q * c + k] = acc[k] / cnt;                                         \
        return 1;                                                                                              \
    }                                                                                                          \
                                                                                                               \
    int nb_dilate_##SUFFIX(T *out, uint8_t *filled, int64_t h, int64_t w, int64_t c, int64_t steps,            \
                           int64_t threads) {                                                                  \
        /* filled: 0 unfilled, 1 filled before this ring, 2 a candidate of this ring (read as unfilled) */     \
        int64_t *ring = (int64_t *)malloc(sizeof(int64_t) * (size_t)(h * w > 0 ? h * w : 1));                  \
        int64_t *next = (int64_t *)malloc(sizeof(int64_t) * (size_t)(h * w > 0 ? h * w : 1));                  \
        uint8_t *mark = (uint8_t *)calloc((size_t)(h * w > 0 ? h * w : 1), 1);                                 \
        int64_t m = 0;                                                                                         \
        const int nt = threads > 1 ? (int)threads : 1, big = nt > 1 && h * w >= NB_ROWS_MIN;                   \
        (void)nt;                                                                                              \
        (void)big;                                                                                             \
        if (ring == NULL || next == NULL || mark == NULL || c > 64) {                                          \
            free(ring);                                                                                        \
            free(next);                                                                                        \
            free(mark);                                                                                        \
            return 0;                                                                                          \
        }                                                                                                      \
        for (int64_t step = 0; step < steps; step++) {                                                         \
            int64_t n = 0;                                                                                     \
            if (step == 0) { /* the first ring: every unfilled texel next to a filled one (rows over the team: \
                                each writes its own texels and reads only texels filled before) */              \
                NB_ROWS                                                                                        \
                for (int64_t y = 0; y < h; y++)                                                                \
                    for (int64_t q = y * w; q < (y + 1) * w; q++)                                              \
                        if (!filled[q] && nb_fill_##SUFFIX(out, filled, h, w, c, q)) mark[q] = 1;              \
                for (int64_t q = 0; q < h * w; q++)                                                            \
                    if (mark[q]) next[n++] = q;                                                                \
                for (int64_t s = 0; s < n; s++) filled[next[s]] = 2;                                           \
            } else { /* the next ring: the unfilled neighbours of the last one */                             \
                for (int64_t s = 0; s < m; s++) {                                                              \
                    int64_t y = ring[s] / w, x = ring[s] % w;                                                  \
                    for (int j = 0; j < 8; j++) {                                                              \
                        int64_t ny = y + NB_DI[j], nx = x + NB_DJ[j];                                          \
                        if (ny < 0 || ny >= h || nx < 0 || nx >= w || filled[ny * w + nx]) continue;           \
                        filled[ny * w + nx] = 2;                                                               \
                        next[n++] = ny * w + nx;                                                               \
                    }                                                                                          \
                }                                                                                              \
                for (int64_t s = 0; s < n; s++) nb_fill_##SUFFIX(out, filled, h, w, c, next[s]);               \
            }                                                                                                  \
            for (int64_t s = 0; s < n; s++) filled[next[s]] = 1;                                               \
            int64_t *t = ring;                                                                                 \
            ring = next;                                                                                       \
            next = t;                                                                                          \
            m = n;                                                                                             \
            if (m == 0) break;                                                                                 \
        }                                                                                                      \
        free(ring);                                                                                            \
        free(next);                                                                                            \
        free(mark);                                                                                            \
        return 1;                                                                                              \
    }

NB_PADDING(float, f32)
NB_PADDING(double, f64)
