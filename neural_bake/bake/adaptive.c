/* Interpolation inside accepted cells: the C kernels of neural_bake.bake.adaptive._interpolate (bilinear) and
   _interpolate_quadratic, and of the cells' tests _surplus_ok and _quadratic_ok (their torch paths are the references; the tests
   hold each pair together in float64, and the interpolations within float32's precision of a float32 reference).

   nb_interp_cells(flat_index, wg, r0, c0, n_cells, k, points, normals, values, colors, n_colors, done, interpolated,
   valid, extrapolate, direction_eps): for every accepted cell of side k with top-left position (r0, c0) on the
   sample grid (flat_index: the (hg, wg) grid of sample indices, -1 where none), every sample of its closed square
   that is not one of its 3x3 nodes and not yet done takes the fields interpolated from the four nodes of its
   quarter: its coordinates (t, u) in the least-squares parallelogram of those four points in space, clamped to
   [-extrapolate, 1 + extrapolate] (t = u = 0.5 where the quad is no parallelogram), bilinear weights; the unit
   normal is the weighted sum renormalised (its length clamped below at direction_eps), f the weighted sum of each
   node's first-order extrapolation f_i + n_i . (p - p_i), colours the weighted sum. Samples are marked done,
   interpolated and valid. Arrays: points, normals (M, 3), values (M,), colors (M, n_colors) float64 row-major
   (colors NULL when n_colors is 0); done, interpolated, valid (M,) uint8. A sample on the edge two cells share
   takes the interpolation of the cell whose (r0 / k + c0 / k) is even (of a checkerboard of the cells, its black
   ones, done first: two cells of one colour share no sample but nodes). The last argument, threads: where built
   with OpenMP, each colour's cells over a team of that many threads, so every sample takes the same value on any
   number of threads and in any order of the cells. Both entries take it. */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

static inline double nb_clamp(double x, double lo, double hi) { return x < lo ? lo : (x > hi ? hi : x); }

/* The least-squares parallelogram coordinates (t, u) of point p in the quad c0..c3 (corner order (0,0), (0,1),
   (1,0), (1,1)), unclamped; returns 0 where the quad is no parallelogram
   (t = u = 0.5 then). */
static int nb_coordinates(const double *c0, const double *c1, const double *c2, const double *c3, const double *p,
                          double extrapolate, double direction_eps, double *t, double *u) {
    double et[3], eu[3], d[3];
    for (int i = 0; i < 3; i++) {
        et[i] = 0.5 * (c2[i] - c0[i] + c3[i] - c1[i]);
        eu[i] = 0.5 * (c1[i] - c0[i] + c3[i] - c2[i]);
        d[i] = p[i] - 0.25 * (c0[i] + c1[i] + c2[i] + c3[i]) + 0.5 * (et[i] + eu[i]);
    }
    const double aa = et[0] * et[0] + et[1] * et[1] + et[2] * et[2];
    const double bb = et[0] * eu[0] + et[1] * eu[1] + et[2] * eu[2];
    const double cc = eu[0] * eu[0] + eu[1] * eu[1] + eu[2] * eu[2];
    const double rt = et[0] * d[0] + et[1] * d[1] + et[2] * d[2];
    const double ru = eu[0] * d[0] + eu[1] * d[1] + eu[2] * d[2];
    const double det = aa * cc - bb * bb;
    const double ac = aa * cc > direction_eps ? aa * cc : direction_eps;
    if (!(det > 64.0 * DBL_EPSILON * ac)) {
        *t = *u = 0.5;
        return 0;
    }
    *t = nb_clamp((cc * rt - bb * ru) / det, -extrapolate, 1.0 + extrapolate);
    *u = nb_clamp((aa * ru - bb * rt) / det, -extrapolate, 1.0 + extrapolate);
    return 1;
}

/* The blend at point pa of the nodes node[0..nw) with weights w: the unit normal n_out (the weighted sum
   renormalised, its length clamped below at direction_eps) and f (*f_out) from each node's first-order
   extrapolation f_j + n_j . (pa - p_j). */
static void nb_blend_normal_value(const int64_t *node, const double *w, int nw, const double *pa, const double *points,
                                  const double *normals, const double *values, double direction_eps, double *n_out,
                                  double *f_out) {
    double n[3] = {0.0, 0.0, 0.0}, f = 0.0;
    for (int j = 0; j < nw; j++) {
        const double *nj = normals + 3 * node[j], *pj = points + 3 * node[j];
        for (int i = 0; i < 3; i++) n[i] += w[j] * nj[i];
        f += w[j] * (values[node[j]] + ((pa[0] - pj[0]) * nj[0] + (pa[1] - pj[1]) * nj[1] + (pa[2] - pj[2]) * nj[2]));
    }
    double length = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (length < direction_eps) length = direction_eps;
    for (int i = 0; i < 3; i++) n_out[i] = n[i] / length;
    *f_out = f;
}

/* Colour channel c of the blend of the nodes node[0..nw) with weights w. */
static double nb_blend_colour(const int64_t *node, const double *w, int nw, const double *colors, int64_t n_colors,
                              int64_t c) {
    double sum = 0.0;
    for (int j = 0; j < nw; j++) sum += w[j] * colors[n_colors * node[j] + c];
    return sum;
}

/* Whether the blend of the nodes node[0..nw) with weights w at sample idx lies within the tolerances of the sample's
   own fields: the unit normal within the squared chord chord2, f within value_tol, each colour channel within
   color_tol (the cells' tests). */
static int nb_blend_within(const int64_t *node, const double *w, int nw, int64_t idx, const double *points,
                           const double *normals, const double *values, const double *colors, int64_t n_colors,
                           double chord2, double value_tol, double color_tol, double direction_eps) {
    double n[3], f, d2 = 0.0;
    nb_blend_normal_value(node, w, nw, points + 3 * idx, points, normals, values, direction_eps, n, &f);
    for (int c = 0; c < 3; c++) d2 += (n[c] - normals[3 * idx + c]) * (n[c] - normals[3 * idx + c]);
    int good = d2 <= chord2 && fabs(f - values[idx]) <= value_tol;
    for (int64_t c = 0; c < n_colors && good; c++)
        good = fabs(nb_blend_colour(node, w, nw, colors, n_colors, c) - colors[n_colors * idx + c]) <= color_tol;
    return good;
}

/* Sample idx takes the blend of the nodes node[0..nw) with weights w (nb_blend_normal_value, the colours
   nb_blend_colour); and is marked done, interpolated and valid. */
static void nb_blend(const int64_t *node, const double *w, int nw, int64_t idx, const double *points, double *normals,
                     double *values, double *colors, int64_t n_colors, uint8_t *done, uint8_t *interpolated,
                     uint8_t *valid, double direction_eps) {
    double n[3], f;
    nb_blend_normal_value(node, w, nw, points + 3 * idx, points, normals, values, direction_eps, n, &f);
    for (int i = 0; i < 3; i++) normals[3 * idx + i] = n[i];
    values[idx] = f;
    for (int64_t c = 0; c < n_colors; c++) colors[n_colors * idx + c] = nb_blend_colour(node, w, nw, colors, n_colors, c);
    done[idx] = 1;
    interpolated[idx] = 1;
    valid[idx] = 1;
}

/* Calls at(dr, dc) for every position (dr, dc) of a cell of side k's closed square (each sample is written once,
   from the cell's nodes, so the order within a cell does not change a value). */
#define NB_FOR_CELL(k, at)                                                                                     \
    do {                                                                                                       \
        for (int64_t dr = 0; dr <= (k); dr++)                                                                  \
            for (int64_t dc = 0; dc <= (k); dc++) at(dr, dc);                                                  \
    } while (0)

/* The cell's colour on the checkerboard of cells of side k: 0 (done first) or 1. */
static inline int nb_colour(int64_t r0, int64_t c0, int64_t k) { return (int)((r0 / k + c0 / k) & 1); }

static void nb_interp_cell(const int64_t *flat_index, int64_t wg, int64_t r0, int64_t c0, int64_t k,
                           const double *points, double *normals, double *values, double *colors, int64_t n_colors,
                           uint8_t *done, uint8_t *interpolated, uint8_t *valid, double extrapolate,
                           double direction_eps) {
    const int64_t h = k / 2;
    const int64_t base = r0 * wg + c0;
#define NB_AT(dr_, dc_)                                                                                        \
    do {                                                                                                       \
        const int64_t ar = (dr_), ac = (dc_);                                                                  \
        if (ar % h == 0 && ac % h == 0) break; /* a node: evaluated */                                        \
        const int64_t idx = flat_index[base + ar * wg + ac];                                                   \
        if (done[idx]) break;                                                                                  \
        const int64_t a = ar / h < 1 ? ar / h : 1, b = ac / h < 1 ? ac / h : 1;                                \
        int64_t corner[4];                                                                                     \
        corner[0] = flat_index[base + (a * wg + b) * h];                                                       \
        corner[1] = flat_index[base + (a * wg + b + 1) * h];                                                   \
        corner[2] = flat_index[base + ((a + 1) * wg + b) * h];                                                 \
        corner[3] = flat_index[base + ((a + 1) * wg + b + 1) * h];                                             \
        double t, u;                                                                                           \
        nb_coordinates(points + 3 * corner[0], points + 3 * corner[1], points + 3 * corner[2],                 \
                       points + 3 * corner[3], points + 3 * idx, extrapolate, direction_eps, &t, &u);          \
        const double w[4] = {(1 - t) * (1 - u), (1 - t) * u, t * (1 - u), t * u};                              \
        nb_blend(corner, w, 4, idx, points, normals, values, colors, n_colors, done, interpolated, valid,      \
                 direction_eps);                                                                               \
    } while (0)
    NB_FOR_CELL(k, NB_AT);
#undef NB_AT
}

/* Cells handled at once by one thread of the team (a cell of side 4 holds 16 samples to interpolate). */
#define NB_CELLS_CHUNK 64

void nb_interp_cells(const int64_t *flat_index, int64_t wg, const int64_t *r0, const int64_t *c0, int64_t n_cells,
                     int64_t k, const double *points, double *normals, double *values, double *colors,
                     int64_t n_colors, uint8_t *done, uint8_t *interpolated, uint8_t *valid, double extrapolate,
                     double direction_eps, int64_t threads) {
    (void)threads;
    for (int colour = 0; colour < 2; colour++) {
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, NB_CELLS_CHUNK) num_threads((int)threads) if(threads > 1 && n_cells >= 2 * NB_CELLS_CHUNK)
#endif
        for (int64_t cell = 0; cell < n_cells; cell++)
            if (nb_colour(r0[cell], c0[cell], k) == colour)
                nb_interp_cell(flat_index, wg, r0[cell], c0[cell], k, points, normals, values, colors, n_colors, done,
                               interpolated, valid, extrapolate, direction_eps);
    }
}

/* The tensor-product quadratic Lagrange basis on the nodes {0, 1/2, 1}^2 at (t, u), in node order (row index with
   t, column index with u). */
static void nb_lagrange(double t, double u, double *out) {
    const double bt[3] = {2 * (t - 0.5) * (t - 1), -4 * t * (t - 1), 2 * t * (t - 0.5)};
    const double bu[3] = {2 * (u - 0.5) * (u - 1), -4 * u * (u - 1), 2 * u * (u - 0.5)};
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) out[3 * a + b] = bt[a] * bu[b];
}

/* The inverse of the 9x9 matrix m (row-major) into inv by Gauss-Jordan elimination with partial pivoting;
   returns 0 when m is singular or the inverse is not finite. */
static int nb_invert9(const double *m, double *inv) {
    double a[9][18];
    for (int i = 0; i < 9; i++)
        for (int j = 0; j < 18; j++) a[i][j] = j < 9 ? m[9 * i + j] : (j - 9 == i ? 1.0 : 0.0);
    for (int c = 0; c < 9; c++) {
        int piv = c;
        for (int r = c + 1; r < 9; r++)
            if (fabs(a[r][c]) > fabs(a[piv][c])) piv = r;
        if (!(fabs(a[piv][c]) > 0.0)) return 0;
        if (piv != c)
            for (int j = 0; j < 18; j++) {
                double x = a[c][j];
                a[c][j] = a[piv][j];
                a[piv][j] = x;
            }
        const double d = a[c][c];
        for (int j = 0; j < 18; j++) a[c][j] /= d;
        for (int r = 0; r < 9; r++) {
            if (r == c || a[r][c] == 0.0) continue;
            const double f = a[r][c];
            for (int j = 0; j < 18; j++) a[r][j] -= f * a[c][j];
        }
    }
    for (int i = 0; i < 9; i++)
        for (int j = 0; j < 9; j++) {
            inv[9 * i + j] = a[i][9 + j];
            if (!isfinite(inv[9 * i + j])) return 0;
        }
    return 1;
}

/* The quadratic of a cell's 9 nodes (node order): the inverse `inv` of the Lagrange basis's values at the nodes'
   coordinates in the parallelogram of its corners (nodes 0, 2, 6, 8); returns 0 where the nodes are not all in a
   parallelogram or the matrix is singular. */
static int nb_quadratic_fit(const int64_t *node, const double *points, double extrapolate, double direction_eps,
                            double *inv) {
    const double *q0 = points + 3 * node[0], *q1 = points + 3 * node[2];
    const double *q2 = points + 3 * node[6], *q3 = points + 3 * node[8];
    double vander[81];
    for (int j = 0; j < 9; j++) {
        double t, u;
        if (!nb_coordinates(q0, q1, q2, q3, points + 3 * node[j], extrapolate, direction_eps, &t, &u)) return 0;
        nb_lagrange(t, u, vander + 9 * j);
    }
    return nb_invert9(vander, inv);
}

/* The 9 nodes' weights w at point pa of the cell's quadratic (nb_quadratic_fit's inv): the Lagrange basis at pa's
   clamped coordinates, corrected by inv. */
static void nb_quadratic_weights(const int64_t *node, const double *points, const double *pa, const double *inv,
                                 double extrapolate, double direction_eps, double *w) {
    double t, u, basis[9];
    nb_coordinates(points + 3 * node[0], points + 3 * node[2], points + 3 * node[6], points + 3 * node[8], pa,
                   extrapolate, direction_eps, &t, &u);
    nb_lagrange(t, u, basis);
    for (int j = 0; j < 9; j++) {
        double s = 0.0;
        for (int i = 0; i < 9; i++) s += basis[i] * inv[9 * i + j];
        w[j] = s;
    }
}

/* Quadratic interpolation inside accepted cells: the C kernel of neural_bake.bake.adaptive._interpolate_quadratic.
   For every cell of side k at (r0, c0), its 9 nodes (3x3, spacing k/2) fix a quadratic in the cell's spatial
   coordinates (those of nb_coordinates from its four corners): the Lagrange basis on the ideal nodes {0, 1/2, 1}^2
   corrected by the inverse of its values at the actual nodes. A cell whose nodes are not all in a parallelogram or
   whose correction is singular interpolates nothing. Every sample of the cell's closed square not yet done takes
   the quadratic's weights at its clamped coordinates: the normal renormalised, f from each node's first-order
   extrapolation, colours; and is marked done, interpolated and valid. Arguments as nb_interp_cells's. */
static void nb_interp_cell_quadratic(const int64_t *flat_index, int64_t wg, int64_t r0, int64_t c0, int64_t k,
                                     const double *points, double *normals, double *values, double *colors,
                                     int64_t n_colors, uint8_t *done, uint8_t *interpolated, uint8_t *valid,
                                     double extrapolate, double direction_eps) {
    const int64_t h = k / 2;
    const int64_t base = r0 * wg + c0;
    int64_t node[9];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) node[3 * a + b] = flat_index[base + (a * wg + b) * h];
    double inv[81];
    if (!nb_quadratic_fit(node, points, extrapolate, direction_eps, inv)) return;
#define NB_AT(dr_, dc_)                                                                                        \
    do {                                                                                                       \
        const int64_t idx = flat_index[base + (dr_) * wg + (dc_)];                                             \
        if (done[idx]) break;                                                                                  \
        double w[9];                                                                                           \
        nb_quadratic_weights(node, points, points + 3 * idx, inv, extrapolate, direction_eps, w);              \
        nb_blend(node, w, 9, idx, points, normals, values, colors, n_colors, done, interpolated, valid,        \
                 direction_eps);                                                                               \
    } while (0)
    NB_FOR_CELL(k, NB_AT);
#undef NB_AT
}

void nb_interp_cells_quadratic(const int64_t *flat_index, int64_t wg, const int64_t *r0, const int64_t *c0,
                               int64_t n_cells, int64_t k, const double *points, double *normals, double *values,
                               double *colors, int64_t n_colors, uint8_t *done, uint8_t *interpolated, uint8_t *valid,
                               double extrapolate, double direction_eps, int64_t threads) {
    /* as nb_interp_cells (cells of side 8 and up hold four times the samples of side 4: a quarter of the chunk) */
    (void)threads;
    for (int colour = 0; colour < 2; colour++) {
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, NB_CELLS_CHUNK / 4) num_threads((int)threads) if(threads > 1 && n_cells >= NB_CELLS_CHUNK / 2)
#endif
        for (int64_t cell = 0; cell < n_cells; cell++)
            if (nb_colour(r0[cell], c0[cell], k) == colour)
                nb_interp_cell_quadratic(flat_index, wg, r0[cell], c0[cell], k, points, normals, values, colors,
                                         n_colors, done, interpolated, valid, extrapolate, direction_eps);
    }
}

/* The quadratic test: the C kernel of neural_bake.bake.adaptive._quadratic_ok. For each of n_cells cells, its 9 nodes
   (nodes, (n_cells, 9) sample indices, node order) fix the quadratic of nb_interp_cell_quadratic; at its 4 test
   points (tests, (n_cells, 4) sample indices, all evaluated) the quadratic's unit normal must lie within the chord
   `chord` of the sample's own (|a - b| <= chord), f within value_tol and every colour channel within color_tol.
   ok (n_cells,) uint8: 1 where every node and test sample is valid, the nodes fix a quadratic and all four test
   points pass. Cells over a team of `threads` where built with OpenMP (each cell writes its own ok). */
void nb_quadratic_test(const int64_t *nodes, const int64_t *tests, int64_t n_cells, const double *points,
                       const double *normals, const double *values, const double *colors, int64_t n_colors,
                       const uint8_t *valid, double chord, double value_tol, double color_tol, double extrapolate,
                       double direction_eps, uint8_t *ok, int64_t threads) {
    const double chord2 = chord * chord;
    (void)threads;
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, NB_CELLS_CHUNK) num_threads((int)threads)
#endif
    for (int64_t cell = 0; cell < n_cells; cell++) {
        const int64_t *node = nodes + 9 * cell, *test = tests + 4 * cell;
        int good = 1;
        for (int j = 0; j < 9 && good; j++) good = valid[node[j]];
        for (int j = 0; j < 4 && good; j++) good = valid[test[j]];
        double inv[81];
        good = good && nb_quadratic_fit(node, points, extrapolate, direction_eps, inv);
        for (int i = 0; i < 4 && good; i++) {
            const int64_t idx = test[i];
            double w[9];
            nb_quadratic_weights(node, points, points + 3 * idx, inv, extrapolate, direction_eps, w);
            good = nb_blend_within(node, w, 9, idx, points, normals, values, colors, n_colors, chord2, value_tol,
                                   color_tol, direction_eps);
        }
        ok[cell] = (uint8_t)good;
    }
}

/* The bilinear (hierarchical surplus) test: the C kernel of neural_bake.bake.adaptive._surplus_ok. For each of n_cells
   cells, its 9 nodes (nodes, (n_cells, 9) sample indices, node order), the five that are not corners (the edges'
   midpoints and the centre) must lie within the tolerances (as nb_quadratic_test's) of their blend from the four
   corners of the cell (nb_coordinates in the corners' parallelogram, bilinear weights, nb_blend_normal_value).
   ok (n_cells,) uint8: 1 where every node is valid and all five pass. Cells over a team of `threads` where built with
   OpenMP (each cell writes its own ok). */
void nb_surplus_test(const int64_t *nodes, int64_t n_cells, const double *points, const double *normals,
                     const double *values, const double *colors, int64_t n_colors, const uint8_t *valid, double chord,
                     double value_tol, double color_tol, double extrapolate, double direction_eps, uint8_t *ok,
                     int64_t threads) {
    static const int mids[5] = {1, 3, 4, 5, 7};
    const double chord2 = chord * chord;
    (void)threads;
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, NB_CELLS_CHUNK) num_threads((int)threads)
#endif
    for (int64_t cell = 0; cell < n_cells; cell++) {
        const int64_t *node = nodes + 9 * cell;
        const int64_t corner[4] = {node[0], node[2], node[6], node[8]};
        int good = 1;
        for (int j = 0; j < 9 && good; j++) good = valid[node[j]];
        for (int i = 0; i < 5 && good; i++) {
            const int64_t idx = node[mids[i]];
            double t, u;
            nb_coordinates(points + 3 * corner[0], points + 3 * corner[1], points + 3 * corner[2],
                           points + 3 * corner[3], points + 3 * idx, extrapolate, direction_eps, &t, &u);
            const double w[4] = {(1 - t) * (1 - u), (1 - t) * u, t * (1 - u), t * u};
            good = nb_blend_within(corner, w, 4, idx, points, normals, values, colors, n_colors, chord2, value_tol,
                                   color_tol, direction_eps);
        }
        ok[cell] = (uint8_t)good;
    }
}

static int64_t nb_find(int64_t *parent, int64_t x) {
    while (parent[x] != x) {
        parent[x] = parent[parent[x]]; /* path halving */
        x = parent[x];
    }
    return x;
}

/* nb_face_components(faces, n_faces, n_vertices, parent, labels): the connected components of faces sharing a
   vertex (union-find over the vertices), numbered in the order of their first face: labels (n_faces,) int64.
   faces (n_faces, 3) int64 in [0, n_vertices); parent (n_vertices,) int64 scratch. Returns the number of
   components. */
int64_t nb_face_components(const int64_t *faces, int64_t n_faces, int64_t n_vertices, int64_t *parent,
                           int64_t *labels) {
    for (int64_t v = 0; v < n_vertices; v++) parent[v] = v;
    for (int64_t f = 0; f < n_faces; f++) {
        int64_t r0 = nb_find(parent, faces[3 * f]);
        for (int k = 1; k < 3; k++) {
            int64_t r = nb_find(parent, faces[3 * f + k]);
            if (r != r0) {
                if (r < r0) {
                    parent[r0] = r;
                    r0 = r;
                } else {
                    parent[r] = r0;
                }
            }
        }
    }
    /* the roots' numbers, in the order their first face comes: -(1 + number) marks a numbered root */
    int64_t count = 0;
    for (int64_t f = 0; f < n_faces; f++) labels[f] = nb_find(parent, faces[3 * f]);
    for (int64_t f = 0; f < n_faces; f++) {
        int64_t root = labels[f];
        if (parent[root] >= 0) parent[root] = -(1 + count++);
        labels[f] = -parent[root] - 1;
    }
    return count;
}
