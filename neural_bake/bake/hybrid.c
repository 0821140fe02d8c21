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
