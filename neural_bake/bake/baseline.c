/* The classical bake's per-sample work around the ray casts: the C kernel of neural_bake.bake.baseline (its numpy
   path is the reference; the tests hold the two to the same bits, both computing in the same order in float64).

   nb_rays(points, normals, index, n, rays, threads): the rays (2n, 6) float32 of n samples, origin the point,
   direction + the normal for the first n and - the normal for the next n; the samples the rows index (n,) int64 of
   points, normals (M, 3) float64, or their first n rows where index is NULL.

   nb_pick_hits(t, prim, uv, m, cage, best_t, best_prim, best_uv, threads): per sample the nearer hit of its two
   rays (t, prim, uv as open3d's cast returns them for the 2m rays above: float32, uint32, (2m, 2) float32) that
   is finite and within cage, the + ray on a tie; best_t = +inf, best_prim = 0, best_uv = 0 where neither hits.

   nb_shade(vertices, vertex_normals, faces, prim, uv, m, direction_eps, normals, points, threads): per sample the
   face prim's corner normals and positions blended with open3d's barycentrics (1 − u − v, u, v), the normal
   renormalised by max(|n|, direction_eps). vertices, vertex_normals (V, 3) float64, faces (F, 3) int64, prim (m,)
   int64, uv (m, 2) float64; normals, points (m, 3) float64.

   threads: the samples split over an OpenMP team of that many where built with OpenMP. */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

#define NB_MT_MIN 16384

void nb_rays(const double *points, const double *normals, const int64_t *index, int64_t n, float *rays,
             int64_t threads) {
    (void)threads;
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(threads > 1 ? (int)threads : 1) if(threads > 1 && n >= NB_MT_MIN)
#endif
    for (int64_t s = 0; s < n; s++) {
        const int64_t row = index != NULL ? index[s] : s;
        const double *p = points + 3 * row, *q = normals + 3 * row;
        float *a = rays + 6 * s, *b = rays + 6 * (n + s);
        for (int k = 0; k < 3; k++) {
            a[k] = b[k] = (float)p[k];
            a[3 + k] = (float)q[k];
            b[3 + k] = (float)(-q[k]);
        }
    }
}

void nb_pick_hits(const float *t, const uint32_t *prim, const float *uv, int64_t m, double cage, double *best_t,
                  int64_t *best_prim, double *best_uv, int64_t threads) {
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(threads > 1 ? (int)threads : 1) if(threads > 1 && m >= NB_MT_MIN)
#endif
    for (int64_t s = 0; s < m; s++) {
        double bt = INFINITY;
        int64_t bp = 0;
        double bu = 0.0, bv = 0.0;
        for (int side = 0; side < 2; side++) {
            int64_t r = s + side * m;
            double th = (double)t[r];
            if (isfinite(th) && th <= cage && th < bt) {
                bt = th;
                bp = (int64_t)prim[r];
                bu = (double)uv[2 * r];
                bv = (double)uv[2 * r + 1];
            }
        }
        best_t[s] = bt;
        best_prim[s] = bp;
        best_uv[2 * s] = bu;
        best_uv[2 * s + 1] = bv;
    }
}

void nb_shade(const double *vertices, const double *vertex_normals, const int64_t *faces, const int64_t *prim,
              const double *uv, int64_t m, double direction_eps, double *normals, double *points, int64_t threads) {
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(threads > 1 ? (int)threads : 1) if(threads > 1 && m >= NB_MT_MIN)
#endif
    for (int64_t s = 0; s < m; s++) {
        const int64_t *f = faces + 3 * prim[s];
        double u = uv[2 * s], v = uv[2 * s + 1];
        double w[3] = {1.0 - u - v, u, v};
        double n[3], p[3];
        for (int k = 0; k < 3; k++) {
            n[k] = vertex_normals[3 * f[0] + k] * w[0];
            p[k] = vertices[3 * f[0] + k] * w[0];
        }
        for (int c = 1; c < 3; c++)
            for (int k = 0; k < 3; k++) {
                n[k] += vertex_normals[3 * f[c] + k] * w[c];
                p[k] += vertices[3 * f[c] + k] * w[c];
            }
        double norm = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (!(norm > direction_eps)) norm = direction_eps;
        for (int k = 0; k < 3; k++) {
            normals[3 * s + k] = n[k] / norm;
            points[3 * s + k] = p[k];
        }
    }
}
