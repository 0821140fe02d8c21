/* The multiresolution grid's encoding and its gradient: the C kernel of neural_bake.nets.grid.

   For each point x (N, 3) and level l (R = res[l] cells per side, a table of size[l] rows starting at row
   offset[l], stored densely when dense[l]): u = ((clamp(x, -1, 1) + 1) · 0.5) · R per axis, the cell
   c = min(floor(u), R − 1), the weights 1 − (u − c) and u − c of its low and high vertex per axis, and the 8
   vertices' rows: cx + (R + 1)(cy + (R + 1) cz) for a dense level, else (cx · 1 ^ cy · 2654435761 ^
   cz · 805459861) mod size[l], plus offset[l]. Corner i + 2j + 4k is vertex (i, j, k); its weight is
   wz[k] · wy[j] · wx[i]. The point's features at the level are the weighted sum of those rows (F each),
   written to out[n, l·F + f]: what GridNet._cells, _trilinear and encode compute in torch. A NaN coordinate
   reads a valid cell with NaN weights: its point's features are NaN (an infinite one is clamped like any other).

   nb_grid_encode_{f32,f64}(x, n, table, levels, F, res, size, offset, dense, out, threads): the features,
   level by level (one level's rows stay in the cache), each level's points split over an OpenMP team of
   `threads`.
   nb_grid_backward_{f32,f64}(x, n, grad_out, levels, F, res, size, offset, dense, grad_table, threads): adds
   each point's weighted output gradient into the rows it read (grad_table holds the table's shape, zeroed by
   the caller), split by whole levels (each level owns its rows, so no two threads write one row), points in
   order within a level: the same bits with any thread count. On the calling thread where built without
   OpenMP. */
#include <math.h>
#include <stdint.h>

#define NB_P1 2654435761LL
#define NB_P2 805459861LL

#define NB_CELL(T)                                                                                              \
    static inline void nb_cell_##T(const T *p, int64_t r, T *wlo, T *whi, int64_t *c) {                       \
        T rf = (T)r;                                                                                            \
        for (int a = 0; a < 3; a++) {                                                                           \
            T v = p[a];                                                                                         \
            v = v < (T)-1 ? (T)-1 : (v > (T)1 ? (T)1 : v);                                                      \
            T u = ((v + (T)1) * (T)0.5) * rf;                                                                   \
            T cell = (T)floor((double)u);                                                                       \
            if (cell > rf - (T)1) cell = rf - (T)1;                                                             \
            if (!(cell >= (T)0)) cell = (T)0; /* NaN: a valid cell, NaN weights, so NaN features */             \
            T frac = u - cell;                                                                                  \
            wlo[a] = (T)1 - frac;                                                                               \
            whi[a] = frac;                                                                                      \
            c[a] = (int64_t)cell;                                                                               \
        }                                                                                                       \
    }

/* the 8 rows and weights of one point's cell at one level */
#define NB_CORNERS(T)                                                                                           \
    static inline void nb_corners_##T(const T *p, int64_t r, int64_t sz, int64_t off, int dense, int64_t *row,  \
                                      T *w) {                                                                   \
        T wlo[3], whi[3];                                                                                       \
        int64_t c[3];                                                                                           \
        nb_cell_##T(p, r, wlo, whi, c);                                                                         \
        int64_t side = r + 1;                                                                                   \
        for (int k = 0; k < 2; k++)                                                                             \
            for (int j = 0; j < 2; j++)                                                                         \
                for (int i = 0; i < 2; i++) {                                                                   \
                    int64_t cx = c[0] + i, cy = c[1] + j, cz = c[2] + k;                                        \
                    int64_t idx = dense ? cx + side * (cy + side * cz)                                          \
                                        : (int64_t)(((uint64_t)cx ^ (uint64_t)(cy * NB_P1) ^                    \
                                                     (uint64_t)(cz * NB_P2)) % (uint64_t)sz);                   \
                    int corner = i + 2 * j + 4 * k;                                                             \
                    row[corner] = idx + off;                                                                    \
                    w[corner] = ((k ? whi[2] : wlo[2]) * (j ? whi[1] : wlo[1])) * (i ? whi[0] : wlo[0]);       \
                }                                                                                               \
    }

#define NB_ENCODE(T, NAME)                                                                                      \
    void NAME(const T *x, int64_t n, const T *table, int64_t levels, int64_t F, const int64_t *res,             \
              const int64_t *size, const int64_t *offset, const int64_t *dense, T *out, int64_t threads) {     \
        (void)threads;                                                                                          \
        for (int64_t l = 0; l < levels; l++) { /* level by level: one level's rows stay in the cache */      \
            _Pragma("omp parallel for num_threads(threads) schedule(static) if(threads > 1 && n > 1024)")      \
            for (int64_t q = 0; q < n; q++) {                                                                   \
                int64_t row[8];                                                                                 \
                T w[8];                                                                                         \
                nb_corners_##T(x + 3 * q, res[l], size[l], offset[l], (int)dense[l], row, w);                  \
                T *o = out + q * levels * F + l * F;                                                            \
                for (int64_t f = 0; f < F; f++) {                                                               \
                    T s = 0;                                                                                    \
                    for (int c = 0; c < 8; c++) s += table[row[c] * F + f] * w[c];                              \
                    o[f] = s;                                                                                   \
                }                                                                                               \
            }                                                                                                   \
        }                                                                                                       \
    }

#define NB_BACKWARD(T, NAME)                                                                                    \
    void NAME(const T *x, int64_t n, const T *grad_out, int64_t levels, int64_t F, const int64_t *res,          \
              const int64_t *size, const int64_t *offset, const int64_t *dense, T *grad_table,                  \
              int64_t threads) {                                                                                \
        (void)threads;                                                                                          \
        _Pragma("omp parallel for num_threads(threads) schedule(dynamic, 1) if(threads > 1)")                  \
        for (int64_t l = 0; l < levels; l++) {                                                                  \
            int64_t row[8];                                                                                     \
            T w[8];                                                                                             \
            for (int64_t q = 0; q < n; q++) {                                                                   \
                nb_corners_##T(x + 3 * q, res[l], size[l], offset[l], (int)dense[l], row, w);                  \
                const T *g = grad_out + q * levels * F + l * F;                                                 \
                for (int c = 0; c < 8; c++)                                                                     \
                    for (int64_t f = 0; f < F; f++) grad_table[row[c] * F + f] += g[f] * w[c];                  \
            }                                                                                                   \
        }                                                                                                       \
    }

NB_CELL(float)
NB_CELL(double)
NB_CORNERS(float)
NB_CORNERS(double)
NB_ENCODE(float, nb_grid_encode_f32)
NB_ENCODE(double, nb_grid_encode_f64)
NB_BACKWARD(float, nb_grid_backward_f32)
NB_BACKWARD(double, nb_grid_backward_f64)
