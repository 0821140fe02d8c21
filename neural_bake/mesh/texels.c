/* The UV rasteriser's inner loops: the C kernel of neural_bake.mesh.texels (its numpy functions of the same
   names are the reference, and the tests hold the two equal bit for bit).

   Triangles are UV-face copies with corners xs, ys (K, 3) row-major float64, in sample- or texel-pixel
   coordinates (sample (r, c) centre at x = c, y = r). Every formula is the reference's, operation for
   operation, and the file is built without FMA contraction (neural_bake.nets.native.FLAGS), so the
   barycentrics, spans and distances are the same doubles.

   nb_sample_owners: for each live copy k (ascending), each sample row r of [r0[k], r1[k]] and each sample
     centre of the row's span: the barycentrics; a sample inside (all ≥ -inside_eps) gets owner = the lowest
     such k, a sample strictly inside (all > strict_eps) counts one more in strict[].
   nb_collect_hits: the samples with an owner, in row-major order: copy, row, column and the owner's
     barycentrics, clipped at 0 and renormalised. Returns how many.
   nb_border_hits: for each live copy k (ascending) and each texel of its box [r0, r1] x [c0, c1] not covered:
     if the triangle overlaps the texel's square (separating axes, touching excluded), its closest point to
     the texel centre (distance and clamped barycentrics); each texel keeps the nearest, the lowest k among
     equals. */
#include <math.h>
#include <stdint.h>

static inline void nb_bary(const double *x, const double *y, double px, double py, double *b, double *d) {
    double x0 = x[0], y0 = y[0];
    double e1x = x[1] - x0, e1y = y[1] - y0;
    double e2x = x[2] - x0, e2y = y[2] - y0;
    double dd = e1x * e2y - e2x * e1y;
    double qx = px - x0, qy = py - y0;
    double b1 = (qx * e2y - e2x * qy) / dd;
    double b2 = (e1x * qy - qx * e1y) / dd;
    b[0] = 1.0 - b1 - b2;
    b[1] = b1;
    b[2] = b2;
    *d = dd;
}

static inline double nb_min(double a, double b) { return b < a ? b : a; }
static inline double nb_max(double a, double b) { return b > a ? b : a; }

void nb_sample_owners(const double *xs, const double *ys, const int64_t *live, int64_t n_live,
                      const int64_t *r0, const int64_t *r1, int64_t a, int64_t ws, double span_tol,
                      double flat_eps, double inside_eps, double strict_eps, int64_t *owner, int64_t *strict) {
    for (int64_t n = 0; n < n_live; n++) {
        int64_t k = live[n];
        const double *x = xs + 3 * k, *y = ys + 3 * k;
        for (int64_t r = r0[k]; r <= r1[k]; r++) {
            double py = (double)r, xl = INFINITY, xr = -INFINITY;
            for (int i = 0; i < 3; i++) {
                int j = (i + 1) % 3;
                double xi = x[i], xj = x[j], yi = y[i], yj = y[j], dy = yj - yi;
                if (!(py >= nb_min(yi, yj) - span_tol && py <= nb_max(yi, yj) + span_tol)) continue;
                int flat = fabs(dy) < flat_eps;
                double t = flat ? 0.0 : (py - yi) / dy;
                t = t < 0.0 ? 0.0 : (t > 1.0 ? 1.0 : t);
                double xa = xi + t * (xj - xi);
                double lo = flat ? nb_min(xi, xj) : xa, hi = flat ? nb_max(xi, xj) : xa;
                xl = nb_min(xl, lo);
                xr = nb_max(xr, hi);
            }
            if (!(xl <= xr)) continue;
            double cl_f = ceil(xl - span_tol), cr_f = floor(xr + span_tol);
            int64_t cl = cl_f > 0.0 ? (int64_t)cl_f : 0;
            int64_t cr = cr_f < (double)(ws - 1) ? (int64_t)cr_f : ws - 1;
            int64_t base = (r - a) * ws;
            for (int64_t c = cl; c <= cr; c++) {
                double b[3], d;
                nb_bary(x, y, (double)c, py, b, &d);
                if (b[0] >= -inside_eps && b[1] >= -inside_eps && b[2] >= -inside_eps) {
                    if (k < owner[base + c]) owner[base + c] = k;
                }
                if (b[0] > strict_eps && b[1] > strict_eps && b[2] > strict_eps) strict[base + c] += 1;
            }
        }
    }
}

int64_t nb_collect_hits(const double *xs, const double *ys, const int64_t *owner, int64_t n_samples, int64_t none,
                        int64_t a, int64_t ws, int64_t *out_k, int64_t *out_r, int64_t *out_c, double *out_b) {
    int64_t m = 0;
    for (int64_t s = 0; s < n_samples; s++) {
        int64_t k = owner[s];
        if (k == none) continue;
        int64_t r = s / ws + a, c = s % ws;
        double b[3], d;
        nb_bary(xs + 3 * k, ys + 3 * k, (double)c, (double)r, b, &d);
        for (int i = 0; i < 3; i++) b[i] = b[i] < 0.0 ? 0.0 : b[i];
        double sum = b[0] + b[1] + b[2];
        out_k[m] = k;
        out_r[m] = r;
        out_c[m] = c;
        for (int i = 0; i < 3; i++) out_b[3 * m + i] = b[i] / sum;
        m++;
    }
    return m;
}

void nb_border_hits(const double *xs, const double *ys, const double *area2, const int64_t *live, int64_t n_live,
                    const int64_t *r0, const int64_t *r1, const int64_t *c0, const int64_t *c1, int64_t a, int64_t w,
                    const uint8_t *covered, double overlap_eps, double area_eps, double *best_d, int64_t *best_k,
                    double *best_b) {
    for (int64_t n = 0; n < n_live; n++) {
        int64_t k = live[n];
        const double *x = xs + 3 * k, *y = ys + 3 * k;
        double sgn = area2[k] > 0.0 ? 1.0 : (area2[k] < 0.0 ? -1.0 : 0.0);
        double xmin = nb_min(nb_min(x[0], x[1]), x[2]), xmax = nb_max(nb_max(x[0], x[1]), x[2]);
        double ymin = nb_min(nb_min(y[0], y[1]), y[2]), ymax = nb_max(nb_max(y[0], y[1]), y[2]);
        for (int64_t r = r0[k]; r <= r1[k]; r++) {
            for (int64_t c = c0[k]; c <= c1[k]; c++) {
                int64_t tid = (r - a) * w + c;
                if (covered[tid]) continue;
                double px = (double)c, py = (double)r;
                if (!(nb_max(xmin, px - 0.5) < nb_min(xmax, px + 0.5))) continue;
                if (!(nb_max(ymin, py - 0.5) < nb_min(ymax, py + 0.5))) continue;
                int overlap = 1;
                for (int i = 0; i < 3 && overlap; i++) {
                    int j = (i + 1) % 3;
                    double ex = x[j] - x[i], ey = y[j] - y[i];
                    double e = sgn * (ex * (py - y[i]) - ey * (px - x[i]));
                    overlap = e + 0.5 * (fabs(ex) + fabs(ey)) > overlap_eps;
                }
                if (!overlap) continue;
                double bary[3], d, dist = INFINITY, bb[3] = {0.0, 0.0, 0.0};
                nb_bary(x, y, px, py, bary, &d);
                for (int i = 0; i < 3; i++) {
                    int j = (i + 1) % 3;
                    double ex = x[j] - x[i], ey = y[j] - y[i];
                    double ll = ex * ex + ey * ey;
                    double t = ll > 0.0 ? ((px - x[i]) * ex + (py - y[i]) * ey) / ll : 0.0;
                    t = t < 0.0 ? 0.0 : (t > 1.0 ? 1.0 : t);
                    double di = hypot(x[i] + t * ex - px, y[i] + t * ey - py);
                    if (di < dist) {
                        dist = di;
                        bb[0] = bb[1] = bb[2] = 0.0;
                        bb[i] = 1.0 - t;
                        bb[j] = t;
                    }
                }
                if (bary[0] >= 0.0 && bary[1] >= 0.0 && bary[2] >= 0.0 && fabs(d) > area_eps) {
                    dist = 0.0;
                    bb[0] = bary[0];
                    bb[1] = bary[1];
                    bb[2] = bary[2];
                }
                if (dist < best_d[tid]) {
                    best_d[tid] = dist;
                    best_k[tid] = k;
                    best_b[3 * tid] = bb[0];
                    best_b[3 * tid + 1] = bb[1];
                    best_b[3 * tid + 2] = bb[2];
                }
            }
        }
    }
}

/* nb_interpolate_corners: per sample m, the corner table (3, F, 10) (corner, face, attribute: position,
   vertex normal, tangent xyz and handedness) weighted by the barycentrics, summed corner by corner; the
   normal and the tangent divided by their lengths (NaN where a length is not above underflow_eps) and the
   handedness's sign (-1 where negative, else 1). */
void nb_interpolate_corners(const double *table, int64_t n_faces, const int64_t *face, const double *bary,
                            int64_t m, double underflow_eps, double *points, double *normal, double *tangent,
                            double *sign) {
    for (int64_t s = 0; s < m; s++) {
        int64_t f = face[s];
        double acc[10];
        const double *c0 = table + 10 * f, *c1 = table + 10 * (n_faces + f), *c2 = table + 10 * (2 * n_faces + f);
        double b0 = bary[3 * s], b1 = bary[3 * s + 1], b2 = bary[3 * s + 2];
        for (int i = 0; i < 10; i++) acc[i] = c0[i] * b0;
        for (int i = 0; i < 10; i++) acc[i] = acc[i] + c1[i] * b1;
        for (int i = 0; i < 10; i++) acc[i] = acc[i] + c2[i] * b2;
        for (int i = 0; i < 3; i++) points[3 * s + i] = acc[i];
        double *outs[2] = {normal + 3 * s, tangent + 3 * s};
        for (int o = 0; o < 2; o++) {
            const double *v = acc + 3 + 3 * o;
            double length = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            for (int i = 0; i < 3; i++) outs[o][i] = length > underflow_eps ? v[i] / length : NAN;
        }
        sign[s] = acc[9] < 0.0 ? -1.0 : 1.0;
    }
}

/* nb_signed_cross: per sample, out = sign * cross(n, t) (the bitangent from the unit normal, the unit tangent and
   the handedness's sign), the same operations in the same order as the numpy path. n, t, out (m, 3), sign (m,)
   float64. */
void nb_signed_cross(const double *n, const double *t, const double *sign, int64_t m, double *out) {
    for (int64_t s = 0; s < m; s++) {
        const double *a = n + 3 * s, *b = t + 3 * s;
        double *o = out + 3 * s;
        o[0] = sign[s] * (a[1] * b[2] - a[2] * b[1]);
        o[1] = sign[s] * (a[2] * b[0] - a[0] * b[2]);
        o[2] = sign[s] * (a[0] * b[1] - a[1] * b[0]);
    }
}
