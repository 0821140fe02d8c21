/* The hybrid's ring: the C kernel of neural_bake.bake.hybrid.HybridFallback._near (its numpy path is the reference;
   the tests hold the two to the same answers).

   nb_near(row, col, h, w, seeds, n_seeds, candidates, n_candidates, side, reach, supersample, out, threads): which
   candidates lie near a seed. row, col (M,) int64: each sample's texel, row relative to the band (0 <= row < h,
   0 <= col < w); seeds (n_seeds,) and candidates (n_candidates,) int64 sample indices; side (M,) int16 or NULL:
   a candidate's own reach in sample-grid positions where above 0 (at most `reach`), else `reach`. A reach of k
   positions is ceil(k / supersample) + 1 texels: out[i] = 1 when a seed's texel lies within that many texels of
   candidate i's in both row and column (a square), else 0. The seeds' texels are counted from an integral image;
   the candidates split over an OpenMP team of `threads` where built with OpenMP. Returns 0 (out untouched) when
   its scratch cannot be allocated. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#define NB_MT_MIN 16384

int nb_near(const int64_t *row, const int64_t *col, int64_t h, int64_t w, const int64_t *seeds, int64_t n_seeds,
            const int64_t *candidates, int64_t n_candidates, const int16_t *side, int64_t reach, int64_t supersample,
            uint8_t *out, int64_t threads) {
    const int64_t stride = w + 1;
    int32_t *sum = (int32_t *)calloc((size_t)((h + 1) * stride), sizeof(int32_t));
    if (sum == NULL) return 0;
    (void)threads;
    for (int64_t i = 0; i < n_seeds; i++) sum[(row[seeds[i]] + 1) * stride + col[seeds[i]] + 1] = 1;
    for (int64_t y = 1; y <= h; y++) { /* sum[y][x]: the seeds in rows < y, columns < x */
        int32_t run = 0;
        int32_t *r = sum + y * stride, *above = r - stride;
        for (int64_t x = 1; x <= w; x++) {
            run += r[x];
            r[x] = above[x] + run;
        }
    }
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads((int)threads) if(threads > 1 && n_candidates >= NB_MT_MIN)
#endif
    for (int64_t i = 0; i < n_candidates; i++) {
        const int64_t s = candidates[i];
        int64_t k = reach;
        if (side != NULL && side[s] > 0 && side[s] < reach) k = side[s];
        const int64_t t = (k + supersample - 1) / supersample + 1;
        const int64_t top = row[s] - t < 0 ? 0 : row[s] - t, bottom = row[s] + t + 1 > h ? h : row[s] + t + 1;
        const int64_t left = col[s] - t < 0 ? 0 : col[s] - t, right = col[s] + t + 1 > w ? w : col[s] + t + 1;
        out[i] = (sum[bottom * stride + right] - sum[top * stride + right] - sum[bottom * stride + left]
                  + sum[top * stride + left]) > 0;
    }
    free(sum);
    return 1;
}

/* nb_decide(idx, n, neural, valid, source_normals, cos_angle, points, values, source_points, to_x, to_p, near_dist,
   est_tol, off, invalid, near, est, threads): the hybrid's per-sample rules before f at the source is needed, the C
   kernel of HybridFallback._decide's angle and validity rules and _source_values' first-order estimate (numpy's
   path is the reference). For sample i (band row idx[i]): invalid = !valid; off = !(neural . source_normal >=
   cos_angle) (unit vectors); where neither holds and values is not NULL, the texel point x = points[idx] and the
   source point p = source_points[i] are taken to the field's frame (to_x, to_p: {apply, s_m, c_m (3), s_f, c_f (3)}:
   q = y / s_m + c_m, then (q - c_f) * s_f where apply is 1), est = values[idx] + neural . (p - x), and near = valid,
   est finite, |p - x| < near_dist and |est| < est_tol. near = 0 and est = NaN elsewhere. neural, points (M, 3),
   valid (M,) uint8, values (M,) float64; source_normals, source_points (n, 3); off, invalid, near (n,) uint8. */
static inline void nb_frame(const double *y, const double *t, double *out) {
    for (int k = 0; k < 3; k++) out[k] = t[0] != 0.0 ? ((y[k] / t[1] + t[2 + k]) - t[6 + k]) * t[5] : y[k];
}

void nb_decide(const int64_t *idx, int64_t n, const double *neural, const uint8_t *valid, const double *source_normals,
               double cos_angle, const double *points, const double *values, const double *source_points,
               const double *to_x, const double *to_p, double near_dist, double est_tol, uint8_t *off,
               uint8_t *invalid, uint8_t *near, double *est, int64_t threads) {
    (void)threads;
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads((int)threads) if(threads > 1 && n >= NB_MT_MIN)
#endif
    for (int64_t i = 0; i < n; i++) {
        const int64_t s = idx[i];
        const double *g = neural + 3 * s, *q = source_normals + 3 * i;
        const double cosine = (g[0] * q[0] + g[1] * q[1]) + g[2] * q[2];
        invalid[i] = !valid[s];
        off[i] = !(cosine >= cos_angle);
        near[i] = 0;
        est[i] = NAN;
        if (invalid[i] || off[i] || values == NULL) continue;
        double x[3], p[3], step[3];
        nb_frame(points + 3 * s, to_x, x);
        nb_frame(source_points + 3 * i, to_p, p);
        for (int k = 0; k < 3; k++) step[k] = p[k] - x[k];
        const double dist = sqrt((step[0] * step[0] + step[1] * step[1]) + step[2] * step[2]);
        const double e = values[s] + ((g[0] * step[0] + g[1] * step[1]) + g[2] * step[2]);
        est[i] = e;
        near[i] = isfinite(e) && dist < near_dist && fabs(e) < est_tol;
    }
}

/* nb_keep_rays(index, n, x, normals, points, hit, out_normals, out_points, out_hit, out_values, out_done, threads): the
   classical bake of n samples kept in the band's (M,) arrays: for s < n, row = index[s], out_normals[row] =
   normals[s], out_points[row] = points[s], out_hit[row] = hit[s], out_done[row] = 1 and out_values[row] =
   (x[row] − points[s])·normals[s], the source's signed distance to first order. x (M, 3) float64: the band's sample
   points, in the frame of points; normals, points (n, 3) float64; hit (n,) uint8; out_normals, out_points (M, 3)
   float64, out_values (M,) float64, out_hit, out_done (M,) uint8. The rows split over an OpenMP team of `threads`. */
void nb_keep_rays(const int64_t *index, int64_t n, const double *x, const double *normals, const double *points,
                  const uint8_t *hit, double *out_normals, double *out_points, uint8_t *out_hit, double *out_values,
                  uint8_t *out_done, int64_t threads) {
    (void)threads;
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads((int)threads) if(threads > 1 && n >= NB_MT_MIN)
#endif
    for (int64_t s = 0; s < n; s++) {
        const int64_t row = index[s];
        const double *nrm = normals + 3 * s, *p = points + 3 * s, *q = x + 3 * row;
        double v = 0.0;
        for (int k = 0; k < 3; k++) {
            out_normals[3 * row + k] = nrm[k];
            out_points[3 * row + k] = p[k];
            v += (q[k] - p[k]) * nrm[k];
        }
        out_values[row] = v;
        out_hit[row] = hit[s];
        out_done[row] = 1;
    }
}
