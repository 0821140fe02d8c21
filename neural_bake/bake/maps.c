/* Tangent-space encoding of object-space normals: the C kernel of neural_bake.bake.maps.encode_tangent_space
   (its numpy path is the reference; the tests hold the two within a few ulps).

   nb_encode_tangent(n, t, b, g, m, det_rel_eps, direction_eps, directx, out, ok): per sample, the inverse of
   the matrix with columns T, B, N applied to n (rows cross(B, N), cross(N, T), cross(T, B), the sign of the
   determinant), renormalised; a singular frame (|det| not above det_rel_eps · |T||B||N|), a non-finite
   input or a zero result gives (0, 0, 1) and ok = 0. directx negates y. All arrays (m, 3) float64 row-major,
   ok (m,) uint8. The last argument, threads: the samples split over an OpenMP team of that many where built with
   OpenMP (each computed as on one thread); nb_normal_map takes it too. */
#include <math.h>
#include <stdint.h>

static inline void nb_cross(const double *a, const double *b, double *o) {
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}

static inline double nb_dot(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* samples or texels below which the threaded entries stay on the calling thread (a team's wake-up costs more) */
#define NB_MT_MIN 16384

void nb_encode_tangent(const double *n, const double *t, const double *b, const double *g, int64_t m,
                       double det_rel_eps, double direction_eps, int directx, double *out, uint8_t *ok,
                       int64_t threads) {
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(threads > 1 ? (int)threads : 1) if(threads > 1 && m >= NB_MT_MIN)
#endif
    for (int64_t s = 0; s < m; s++) {
        const double *ns = n + 3 * s, *ts = t + 3 * s, *bs = b + 3 * s, *gs = g + 3 * s;
        double r0[3], r1[3], r2[3], x[3];
        nb_cross(bs, gs, r0);
        nb_cross(gs, ts, r1);
        nb_cross(ts, bs, r2);
        double det = nb_dot(ts, r0);
        double scale = sqrt(nb_dot(ts, ts)) * sqrt(nb_dot(bs, bs)) * sqrt(nb_dot(gs, gs));
        int good = isfinite(det) && fabs(det) > det_rel_eps * (scale > direction_eps ? scale : direction_eps)
                   && isfinite(ns[0]) && isfinite(ns[1]) && isfinite(ns[2]);
        double sg = det > 0.0 ? 1.0 : (det < 0.0 ? -1.0 : 0.0);
        x[0] = nb_dot(r0, ns) * sg;
        x[1] = nb_dot(r1, ns) * sg;
        x[2] = nb_dot(r2, ns) * sg;
        double norm = sqrt(nb_dot(x, x));
        good = good && norm > direction_eps && isfinite(norm);
        double *o = out + 3 * s;
        if (good) {
            o[0] = x[0] / norm;
            o[1] = x[1] / norm;
            o[2] = x[2] / norm;
        } else {
            o[0] = 0.0;
            o[1] = 0.0;
            o[2] = 1.0;
        }
        if (directx) o[1] = -o[1];
        ok[s] = (uint8_t)good;
    }
}

/* nb_splat(values, flat, weight, m, c, acc, wsum): the weighted per-sample values added into the image sums in
   place, sample by sample: acc[flat[s] * c + k] += values[s * c + k] * weight[s] and wsum[flat[s]] += weight[s]
   (weight NULL: 1; wsum NULL: not summed). Each sum is formed in double and stored as float, as numpy's
   in-place add of a float64 right-hand side into a float32 image does. values (m, c) float64 row-major, flat (m,)
   int64 texel indices, acc (texels, c) and wsum (texels,) float32. */
void nb_splat(const double *values, const int64_t *flat, const double *weight, int64_t m, int64_t c, float *acc,
              float *wsum) {
    for (int64_t s = 0; s < m; s++) {
        const double w = weight ? weight[s] : 1.0;
        float *a = acc + flat[s] * c;
        const double *v = values + s * c;
        for (int64_t k = 0; k < c; k++) a[k] = (float)((double)a[k] + v[k] * w);
        if (wsum) wsum[flat[s]] = (float)((double)wsum[flat[s]] + w);
    }
}

/* nb_normal_map(vec, n, direction_eps): the summed vectors of n texels (n, 3) float32 turned into the encoded
   normal map in place: each divided by its length, (0, 0, 1) where the length is not above direction_eps (texels
   whose samples cancel out, and the background), then (x + 1) / 2 clipped to [0, 1]. The length in float, as
   numpy's float32 arithmetic forms it. */
void nb_normal_map(float *vec, int64_t n, double direction_eps, int64_t threads) {
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(threads > 1 ? (int)threads : 1) if(threads > 1 && n >= NB_MT_MIN)
#endif
    for (int64_t i = 0; i < n; i++) {
        float *v = vec + 3 * i;
        const float norm = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        float x[3] = {0.0f, 0.0f, 1.0f};
        if ((double)norm > direction_eps)
            for (int k = 0; k < 3; k++) x[k] = v[k] / norm;
        for (int k = 0; k < 3; k++) {
            float e = (x[k] + 1.0f) * 0.5f;
            v[k] = e < 0.0f ? 0.0f : (e > 1.0f ? 1.0f : e);
        }
    }
}
